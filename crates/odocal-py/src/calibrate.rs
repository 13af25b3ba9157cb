//! `odocal.calibrate`: the keyword options read into the library's
//! calibration settings ([`Settings`]: the same keys as a manifest's and,
//! in kebab case, the CLI's flags), the calibration run without the GIL,
//! and the CLI's JSON report.

use std::sync::Arc;

use pyo3::exceptions::{PyRuntimeError, PyTypeError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use odocal::settings::{Caller, ManifestSettings, Resolved, Settings};
use odocal::Drive;
use odocal::ReferenceSpec;
use odocal::{Holdout, Progress};

use crate::convert::{to_json, to_py, type_name};
use crate::drive::{drives_arg, Provenance, PyDrive};
use crate::files::distinct_drives;
use crate::run::{run_detached, with_threads};
use crate::{lib_err, with_schema_version, OdocalError};

/// What to run: the calibration options and where the report validates.
struct CalibrationPlan {
    /// The options, and what became of the manifest's settings.
    resolved: Resolved,
    /// The half held out (`holdout`) or the `validate_on` drives joined.
    holdout: Option<Holdout>,
    /// The `validate_on` drives one by one (several: Ē_p per drive too),
    /// each with its manifest's `[reference]`.
    validate_on: Vec<(Arc<Drive>, Option<ReferenceSpec>)>,
    /// Carry an estimated heading offset to the `validate_on` drives
    /// (`carry_heading_offset=True`) instead of re-estimating each drive's.
    carry_heading_offset: bool,
}

/// The keywords of `odocal.calibrate` besides the calibration settings.
const RUN_KEYWORDS: [&str; 3] = ["holdout", "validate_on", "carry_heading_offset"];

/// Every option `odocal.calibrate` takes as a keyword (`odocal.CALIBRATE_OPTIONS`):
/// the library's settings, then [`RUN_KEYWORDS`].
pub(crate) fn options() -> Vec<&'static str> {
    Settings::KEYS.iter().chain(&RUN_KEYWORDS).copied().collect()
}

/// The half of the drive `holdout=` holds out.
pub(crate) fn parse_holdout(s: &str) -> PyResult<Holdout> {
    match s {
        "first-half" | "first_half" => Ok(Holdout::FirstHalf),
        "second-half" | "second_half" => Ok(Holdout::SecondHalf),
        s => Err(lib_err(odocal::Error::InvalidOption {
            field: "holdout",
            reason: format!("'{s}': use first-half or second-half (the half held out)"),
        })),
    }
}

/// The `validate_on` drives: joined (the hold-out), and one by one with
/// their manifests' `[reference]`.
type ValidationDrives = (Holdout, Vec<(Arc<Drive>, Option<ReferenceSpec>)>);

/// The drives of `validate_on=` (one drive or a list of them).
fn validation_drives(v: &Bound<'_, PyAny>) -> PyResult<ValidationDrives> {
    let (joined, provs) = drives_arg(v, "validate_on")?;
    let drives: Vec<Arc<Drive>> = match v.cast::<PyDrive>() {
        Ok(_) => vec![Arc::clone(&joined)],
        Err(_) => v.try_iter()?.map(|d| Ok(Arc::clone(&d?.cast::<PyDrive>()?.get().drive))).collect::<PyResult<_>>()?,
    };
    let references = provs.iter().map(|p| Ok(p.settings()?.and_then(|s| s.reference))).collect::<PyResult<Vec<_>>>()?;
    Ok((Holdout::Other(Drive::clone(&joined)), drives.into_iter().zip(references).collect()))
}

/// The calibration of `method` and the keyword options: the keywords are
/// the library's settings (`Settings::try_from`), over the manifest's
/// ([`Settings::resolve`]); `holdout` and `validate_on` choose where the
/// report validates. None means "not given", as an absent flag. An unknown
/// keyword raises `TypeError` naming the known ones; a bad value
/// `OdocalError` naming the keyword.
fn plan(
    method: Option<&str>,
    kwargs: Option<&Bound<'_, PyDict>>,
    manifests: &[ManifestSettings],
) -> PyResult<CalibrationPlan> {
    let mut keys = serde_json::Map::new();
    if let Some(m) = method {
        keys.insert("method".into(), m.into());
    }
    let (mut holdout, mut validate_on, mut carry_heading_offset) = (None, None, false);
    for (key, v) in kwargs.into_iter().flat_map(|kw| kw.iter()) {
        let key: String = key.extract()?;
        if v.is_none() {
            continue;
        }
        match key.as_str() {
            "holdout" => {
                let half = v.extract::<String>().map_err(|_| {
                    PyTypeError::new_err(format!(
                        "holdout: give \"first-half\" or \"second-half\" (got {})",
                        type_name(&v)
                    ))
                })?;
                holdout = Some(parse_holdout(&half)?);
            }
            "validate_on" => validate_on = Some(validation_drives(&v)?),
            "carry_heading_offset" => {
                carry_heading_offset = v.extract::<bool>().map_err(|_| {
                    PyTypeError::new_err(format!("carry_heading_offset: give True or False (got {})", type_name(&v)))
                })?;
            }
            // A seed as `simulate`'s: an int 0 … 2^64 − 1, the range named.
            k @ ("seed" | "bootstrap_seed") => {
                keys.insert(key.clone(), crate::convert::seed_of(&v, k)?.into());
            }
            k if Settings::KEYS.contains(&k) => {
                let value = to_json(&v, k)?;
                crate::convert::refuse_bool_for_number(k, &value)?;
                keys.insert(key, value);
            }
            _ => {
                return Err(PyTypeError::new_err(format!(
                    "calibrate() got an unknown option '{key}'; options: {}",
                    options().join(", ")
                )));
            }
        }
    }
    if holdout.is_some() && validate_on.is_some() {
        return Err(lib_err(odocal::Error::InvalidOption {
            field: "validate_on",
            reason: "give holdout or validate_on, not both".into(),
        }));
    }
    let settings = Settings::try_from(serde_json::Value::Object(keys)).map_err(lib_err)?;
    let resolved = settings.resolve(manifests, Caller::Python).map_err(lib_err)?;
    let (validate_on, validate_on_drives) = validate_on.unzip();
    Ok(CalibrationPlan {
        resolved,
        holdout: holdout.or(validate_on),
        validate_on: validate_on_drives.unwrap_or_default(),
        carry_heading_offset,
    })
}

/// The CLI's JSON report: the library report plus `truth` (simulated
/// drives) and `wheel_scale` (manifest imports), as `odocal calibrate --json`.
fn calibrate_json(
    drive: &Drive,
    prov: &Provenance,
    plan: &CalibrationPlan,
    drives: Vec<serde_json::Value>,
    separate: &[Arc<Drive>],
    progress: Option<&(dyn Fn(Progress) + Sync)>,
) -> odocal::Result<serde_json::Value> {
    let split = plan.holdout.as_ref().map(|h| h.split(drive)).transpose()?;
    let held: Option<&Drive> = split.as_ref().map(|(_, held)| held.as_ref());
    let names: Vec<String> = (0..plan.validate_on.len()).map(|i| format!("validate_on[{i}]")).collect();
    let validation: Vec<odocal::ValidationDrive> = names
        .iter()
        .zip(&plan.validate_on)
        .map(|(name, (d, r))| odocal::ValidationDrive { name, drive: d, reference: r.as_ref() })
        .collect();
    // Validation drives: each with the extrinsics that apply to it (odocal::assess::validation_drives).
    let opts = &plan.resolved.options;
    // Several drives fitted whole: the between-drive σ from their separate fits (as the CLI).
    let joined_from: Vec<&Drive> = separate.iter().map(|d| d.as_ref()).collect();
    let run = odocal::Calibration { progress, drives: &joined_from, ..odocal::Calibration::new(drive, opts) };
    let report = match (validation.is_empty(), &plan.holdout) {
        (true, Some(h)) => odocal::Calibration { holdout: Some(h), ..run }.run()?,
        (true, None) => run.run()?,
        (false, _) => odocal::Calibration {
            validate_on: &validation,
            given: plan.resolved.given_extrinsics,
            carry_heading_offset: plan.carry_heading_offset,
            ..run
        }
        .run()?,
    };
    let scored = held.unwrap_or(drive);
    let truth = match &prov.sidecar {
        Some(side) => {
            let segs = odocal::segment::validation_segments(scored, &opts.validation)?;
            Some((side.theta_true, odocal::mean_position_error(scored, &segs, &side.theta_true)?.mean_position_error_m))
        }
        None => None,
    };
    let truth = truth.as_ref().map(|(t, e)| (t, *e));
    let mut v = report.to_json(drives, truth, prov.wheel_scale.as_deref(), Some(&plan.resolved.account))?;
    with_schema_version(&mut v);
    Ok(v)
}

/// Calibrates `drive` (see the Python docstring of `odocal.calibrate`).
/// Returns `(report dict, report JSON text)`.
#[pyfunction]
#[pyo3(signature = (drive, method=None, *, progress=None, threads=None, **options))]
pub(crate) fn calibrate<'py>(
    py: Python<'py>,
    drive: &Bound<'py, PyAny>,
    method: Option<&str>,
    progress: Option<Py<PyAny>>,
    #[pyo3(from_py_with = crate::convert::opt_threads)] threads: Option<usize>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<(Bound<'py, PyAny>, String)> {
    // A progress that cannot be called is refused before the calibration, not after it.
    if let Some(p) = progress.as_ref().filter(|p| !p.bind(py).is_callable()) {
        return Err(PyTypeError::new_err(format!(
            "progress: give a function progress(stage, done, total) (got {})",
            type_name(p.bind(py))
        )));
    }
    let validate_on = options.map(|o| o.get_item("validate_on")).transpose()?.flatten();
    let entries = distinct_drives(py, drive, validate_on.as_ref())?;
    let (inner, provs) = drives_arg(drive, "drive")?;
    // One θ for drives that count wheel revolutions alike, judged on such drives.
    if let Some(why) = crate::drive::wheel_scale_conflict(None, &provs, "drive") {
        return Err(OdocalError::new_err(format!(
            "one θ cannot be calibrated on drives that count wheel revolutions differently: {why}"
        )));
    }
    if let Some(v) = &validate_on {
        let first = provs
            .iter()
            .find_map(|p| p.wheel_scale.clone().map(|w| (p.source.clone().unwrap_or_else(|| "drive".to_string()), w)));
        if let Some(why) = crate::drive::wheel_scale_conflict(first, &crate::drive::provenances(v), "validate_on") {
            return Err(OdocalError::new_err(format!("validate_on: θ would be judged in another unit: {why}")));
        }
    }
    let separate: Vec<Arc<Drive>> = match drive.cast::<PyDrive>() {
        Ok(_) => Vec::new(),
        Err(_) => drive
            .try_iter()?
            .filter_map(|x| x.ok().and_then(|x| x.cast::<PyDrive>().ok().map(|d| Arc::clone(&d.get().drive))))
            .collect(),
    };
    let settings: Vec<ManifestSettings> =
        provs.iter().map(Provenance::settings).collect::<PyResult<Vec<_>>>()?.into_iter().flatten().collect();
    let plan = plan(method, options, &settings)?;
    // Several drives: no single truth (as the CLI); how to read c_e from the first that says.
    let prov = match provs.as_slice() {
        [one] => one.clone(),
        many => Provenance { wheel_scale: many.iter().find_map(|p| p.wheel_scale.clone()), ..Default::default() },
    };
    let mut value = run_detached(py, progress, |cb| {
        with_threads(threads, || calibrate_json(&inner, &prov, &plan, entries, &separate, cb))
    })??
    .map_err(|e| match e {
        e @ odocal::Error::NotObservable { .. } => OdocalError::new_err(format!(
            "{e}; in Python: fix=['c_d', 't_r', 'd'], min_yaw_rate=0 calibrates c_e alone, or pass auto_fix=True"
        )),
        e => lib_err(e),
    })?;
    // The manifests' import warnings, calibration drives first, as the CLI's JSON lists them.
    let validation_provs = validate_on.as_ref().map(crate::drive::provenances).unwrap_or_default();
    crate::drive::with_import_warnings(&mut value, &[provs, validation_provs].concat());
    let text = serde_json::to_string_pretty(&value).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok((to_py(py, &value)?, text))
}
