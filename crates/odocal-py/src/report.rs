//! Calibration reports after the fit: the method's account, parameter
//! files and the HTML report.

use std::path::PathBuf;

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use odocal::model::Theta;
use odocal::Drive;
use odocal::Holdout;

use crate::calibrate::parse_holdout;
use crate::convert::to_py;
use crate::drive::{drives_arg, provenances, Provenance, PyDrive};
use crate::files::{calibration_fingerprints, check_outputs};
use crate::{lib_err, OdocalError};

/// The error for JSON text that is not a calibration report.
fn not_a_report(e: serde_json::Error) -> PyErr {
    PyValueError::new_err(format!("not a calibration report: {e}"))
}

/// A calibration report from its JSON text (the Python report's `_json`).
pub(crate) fn report_from_json(report_json: &str) -> PyResult<odocal::CalibrationReport> {
    serde_json::from_str(report_json).map_err(not_a_report)
}

/// The method's own account of the fit (`CalibrationReport::method_details`
/// of the library: the EIV lines the CLI prints; empty for the other
/// methods) of a calibration report's JSON text.
#[pyfunction]
pub(crate) fn _method_details(report_json: &str) -> PyResult<String> {
    Ok(report_from_json(report_json)?.method_details())
}

/// Reads a parameter file (ROS 2 YAML or JSON, as `--params-out` writes
/// it; library `ParamFile::read`) into the layout of the JSON file:
/// the node `params_node`, or the one node with odocal's parameters.
#[pyfunction]
#[pyo3(signature = (path, *, params_node=None))]
pub(crate) fn read_params<'py>(
    py: Python<'py>,
    path: PathBuf,
    params_node: Option<&str>,
) -> PyResult<Bound<'py, PyAny>> {
    let f = odocal::ParamFile::read(&path, params_node).map_err(lib_err)?;
    to_py(py, &f.to_json())
}

/// Writes the parameter file of a calibration report (its JSON text) as
/// `odocal calibrate --params-out` does: YAML for `.yaml`/`.yml`, JSON for
/// `.json` (library `CalibrationReport::param_file`).
///
/// `drives` are the drives of the report (calibration and validation): a
/// path that is one of their files is refused. `input` (the provenance's;
/// `None`: [`input_names`] of the `calibration` drives, else of the
/// report's). The provenance gains the calibration drives' fingerprints
/// (the report's `drives`). The node is checked by the library
/// (`ParamFile::check_node_name`, as the CLI's `--params-node`).
#[pyfunction]
#[pyo3(signature = (report_json, path, *, input=None, node, mapping, drives=None, calibration=None))]
#[allow(clippy::too_many_arguments)] // one argument per Python keyword
pub(crate) fn _write_params(
    report_json: &str,
    path: PathBuf,
    input: Option<&str>,
    node: &str,
    mapping: &str,
    drives: Option<&Bound<'_, PyAny>>,
    calibration: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    check_against(drives, "write_params(path)", &path)?;
    let value: serde_json::Value = serde_json::from_str(report_json).map_err(not_a_report)?;
    let fingerprints = calibration_fingerprints(&value);
    let wheel_scale = value.get("wheel_scale").and_then(|w| w.as_str()).map(str::to_string);
    let input = match (input, calibration.map(provenances).unwrap_or_default()) {
        (Some(i), _) => i.to_string(),
        (None, provs) if !provs.is_empty() => input_names(&provs),
        (None, _) => report_input(&value),
    };
    let mut f = serde_json::from_value::<odocal::CalibrationReport>(value).map_err(not_a_report)?.param_file(&input);
    f.node = node.to_string();
    f.mapping = mapping.parse().map_err(lib_err)?;
    if let Some(fp) = fingerprints {
        f.provenance.push(("fingerprint".into(), fp));
    }
    // What c_e, c_d and d are per, as `odocal calibrate --params-out` writes it.
    if let Some(w) = wheel_scale {
        f.provenance.push(("wheel_scale".into(), w));
    }
    f.text_for(&path).and_then(|text| odocal::output::write_text(&path, &text)).map_err(lib_err)
}

/// How a parameter file's `provenance.input` names the calibration
/// drives, as `odocal calibrate --params-out` names its drive files: each
/// drive's file, `simulated drive` for one of `odocal.simulate` (as `odocal
/// demo`'s), `python` for one made from arrays; comma separated.
fn input_names(drives: &[Provenance]) -> String {
    let name = |p: &Provenance| match (&p.source, &p.sidecar) {
        (Some(s), _) => s.clone(),
        (None, Some(_)) => "simulated drive".to_string(),
        (None, None) => "python".to_string(),
    };
    drives.iter().map(name).collect::<Vec<_>>().join(", ")
}

/// [`input_names`] from a report's JSON `drives` alone (a report without
/// its drives): each calibration drive's path, `python` for one without.
fn report_input(report: &serde_json::Value) -> String {
    let entries = report["drives"].as_array().map(Vec::as_slice).unwrap_or_default();
    let names: Vec<&str> =
        entries.iter().filter(|e| e["role"] == "calibration").map(|e| e["path"].as_str().unwrap_or("python")).collect();
    if names.is_empty() {
        "python".to_string()
    } else {
        names.join(", ")
    }
}

/// Refuses an output `path` that is a file of one of `drives` (a list of
/// `odocal.Drive`).
fn check_against(drives: Option<&Bound<'_, PyAny>>, role: &str, path: &std::path::Path) -> PyResult<()> {
    let mut provs = Vec::new();
    if let Some(list) = drives {
        for item in list.try_iter()? {
            provs.push(item?.cast::<PyDrive>()?.get().prov.clone());
        }
    }
    check_outputs(&provs.iter().collect::<Vec<_>>(), &[(role, path)])
}

/// Writes the HTML report (odocal-report) of a calibration report (its
/// JSON text) on the drive it was validated on: `drive`, its held-out half
/// (`holdout`), or `validate_on`. Maps the JSON report to the renderer's
/// input in this one place.
#[pyfunction]
#[pyo3(signature = (drive, report_json, path, *, holdout=None, validate_on=None, title=None, drives=None))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn _report_html(
    py: Python<'_>,
    drive: &Bound<'_, PyAny>,
    report_json: &str,
    path: PathBuf,
    holdout: Option<&str>,
    validate_on: Option<&Bound<'_, PyAny>>,
    title: Option<String>,
    drives: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    check_against(drives, "to_html(path)", &path)?;
    let value: serde_json::Value = serde_json::from_str(report_json).map_err(not_a_report)?;
    let fingerprint = calibration_fingerprints(&value);
    // The manifests' import warnings, listed before the calibration's (as the CLI's HTML report).
    let import_warnings: Vec<String> = value["import_warnings"]
        .as_array()
        .map(|w| w.iter().filter_map(|w| w.as_str().map(str::to_string)).collect())
        .unwrap_or_default();
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
    // The first sample of each validation drive in the joined drive, or
    // of each calibration drive.
    let mut starts = Vec::new();
    if let Some(d) = validate_on {
        let lengths: Vec<usize> = match d.cast::<PyDrive>() {
            Ok(one) => vec![one.get().drive.len()],
            Err(_) => d.try_iter()?.map(|x| Ok(x?.cast::<PyDrive>()?.get().drive.len())).collect::<PyResult<_>>()?,
        };
        let mut n = 0;
        for len in lengths {
            starts.push(n);
            n += len;
        }
    }
    let inner = drives_arg(drive, "drive")?.0;
    if validate_on.is_none() {
        // The calibration's own drives (each with its heading offset after a joint fit).
        starts = inner.drive_starts().to_vec();
    }
    let title = title.unwrap_or_else(|| "odocal calibration".into());
    py.detach(move || -> Result<(), String> {
        let split = holdout.as_ref().map(|h| h.split(&inner)).transpose().map_err(|e| e.to_string())?;
        let scored: &Drive = split.as_ref().map_or(&inner, |(_, h)| h.as_ref());
        let segs =
            odocal::segment::validation_segments(scored, &report.options.validation).map_err(|e| e.to_string())?;
        let input = odocal_report::ReportInput {
            provenance: vec![
                ("method".into(), report.method.to_string()),
                ("odocal".into(), env!("CARGO_PKG_VERSION").into()),
                ("from".into(), "Python (odocal.CalibrationReport.to_html)".into()),
                ("σ of θ".into(), report.result_sigma().covers.to_string()),
            ]
            .into_iter()
            .chain(fingerprint.map(|f| ("fingerprint".into(), f)))
            .collect(),
            ..odocal_report::ReportInput::of_calibration(title, &report, (scored, &segs, &starts), truth.as_ref())
        }
        .with_import_warnings(import_warnings);
        odocal_report::write_html(&path, &input).map_err(|e| e.to_string())
    })
    .map_err(OdocalError::new_err)
}
