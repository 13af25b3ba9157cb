//! The files behind drives and the checks of what Python writes and
//! calibrates, as the CLI does them: outputs that would overwrite a drive's
//! files are refused ([`check_outputs`]), a drive given twice is refused
//! ([`distinct_drives`]), and the reader's warnings become Python warnings.

use std::path::Path;
use std::sync::Arc;

use pyo3::exceptions::{PyTypeError, PyUserWarning};
use pyo3::prelude::*;
use pyo3::types::PyString;

use odocal::output::{check_collisions, FileRole};
use odocal::Drive;

use crate::drive::{Provenance, PyDrive};
use crate::lib_err;

/// The files a drive was read from: its CSV and the simulator sidecar
/// beside it, or its manifest, every stream file the manifest names and
/// the parameter file its `[calibration] theta0` names. The files are those of the drive's path as it was read (`prov.file`),
/// whatever the working directory is now.
pub(crate) fn inputs_of(prov: &Provenance) -> Vec<FileRole> {
    let Some(src) = &prov.source else { return Vec::new() };
    let path = prov.file.as_deref().unwrap_or(Path::new(src));
    if odocal::is_manifest_path(path) {
        let mut out = vec![FileRole { role: format!("the manifest {src} of the drive"), path: path.into() }];
        if let Ok(m) = odocal::Manifest::from_path(path) {
            out.extend(
                m.stream_files()
                    .into_iter()
                    .map(|(s, f)| FileRole { role: format!("stream '{s}' of the manifest {src}"), path: f }),
            );
            if let Some(f) = m.theta0_file() {
                out.push(FileRole {
                    role: format!("the [calibration] theta0 parameter file of the manifest {src}"),
                    path: f,
                });
            }
        }
        out
    } else {
        let mut out = vec![FileRole { role: format!("the CSV {src} the drive was read from"), path: path.into() }];
        if let Some(side) = odocal::sim::SimSidecar::file_beside(path) {
            out.push(FileRole { role: format!("the simulator sidecar of {src}"), path: side });
        }
        out
    }
}

/// Refuses outputs (`(role, path)`) that would overwrite a file of the
/// drives `inputs` were read from, or each other.
pub(crate) fn check_outputs(inputs: &[&Provenance], outputs: &[(&str, &Path)]) -> PyResult<()> {
    let ins: Vec<FileRole> = inputs.iter().flat_map(|p| inputs_of(p)).collect();
    let outs: Vec<FileRole> = outputs.iter().map(|(r, p)| FileRole { role: (*r).into(), path: (*p).into() }).collect();
    check_collisions(&ins, &outs).map_err(lib_err)
}

/// Each drive of an argument that takes one drive or a list of them, with
/// its name in errors (`drive`, `drive[1] (b.csv)`) and its provenance.
pub(crate) fn drive_items(v: &Bound<'_, PyAny>, what: &str) -> PyResult<Vec<(String, Arc<Drive>, Provenance)>> {
    let named = |name: String, d: &PyDrive| {
        let name = match &d.prov.source {
            Some(s) => format!("{name} ({s})"),
            None => name,
        };
        (name, Arc::clone(&d.drive), d.prov.clone())
    };
    if let Ok(d) = v.cast::<PyDrive>() {
        return Ok(vec![named(what.to_string(), d.get())]);
    }
    let not_drives = || PyTypeError::new_err(format!("{what}: give an odocal.Drive or a list of them"));
    if v.cast::<PyString>().is_ok() {
        return Err(not_drives());
    }
    let mut out = Vec::new();
    for (i, item) in v.try_iter().map_err(|_| not_drives())?.enumerate() {
        let item = item?;
        let d = item.cast::<PyDrive>().map_err(|_| not_drives())?;
        out.push(named(format!("{what}[{i}]"), d.get()));
    }
    Ok(out)
}

/// Refuses a drive given twice among the calibration drives `drive` and
/// the `validate_on` drives; returns each one's report entry (role, path,
/// fingerprint), as the CLI's JSON `drives`.
pub(crate) fn distinct_drives(
    py: Python<'_>,
    drive: &Bound<'_, PyAny>,
    validate_on: Option<&Bound<'_, PyAny>>,
) -> PyResult<Vec<serde_json::Value>> {
    let mut items = drive_items(drive, "drive")?;
    let calibration = items.len();
    if let Some(v) = validate_on.filter(|v| !v.is_none()) {
        items.extend(drive_items(v, "validate_on")?);
    }
    let prints = py
        .detach(|| {
            let refs: Vec<(&str, &Drive)> = items.iter().map(|(n, d, _)| (n.as_str(), d.as_ref())).collect();
            odocal::refuse_duplicates(&refs)
        })
        .map_err(lib_err)?;
    Ok(items
        .iter()
        .zip(prints)
        .enumerate()
        .map(|(i, ((_, _, prov), fp))| {
            let role = if i < calibration { "calibration" } else { "validation" };
            serde_json::json!({"role": role, "path": prov.source, "fingerprint": fp})
        })
        .collect())
}

/// The fingerprints of a report's calibration drives (its JSON `drives`),
/// comma separated: a parameter file's and the HTML report's provenance.
pub(crate) fn calibration_fingerprints(report: &serde_json::Value) -> Option<String> {
    let drives = report.get("drives")?.as_array()?;
    let prints: Vec<&str> =
        drives.iter().filter(|e| e["role"] == "calibration").filter_map(|e| e["fingerprint"].as_str()).collect();
    (!prints.is_empty()).then(|| prints.join(", "))
}

/// Issues each text as a Python `UserWarning`.
pub(crate) fn warn_all(py: Python<'_>, warnings: &[String]) -> PyResult<()> {
    for w in warnings {
        let msg = std::ffi::CString::new(w.replace('\0', " ")).unwrap_or_default();
        PyErr::warn(py, &py.get_type::<PyUserWarning>(), &msg, 1)?;
    }
    Ok(())
}
