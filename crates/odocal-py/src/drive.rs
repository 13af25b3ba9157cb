//! `odocal.Drive`: a drive made from arrays, read from a CSV or imported
//! from a manifest, with where it came from ([`Provenance`]), and its
//! pickling.

use std::ops::Range;
use std::path::PathBuf;
use std::sync::Arc;

use numpy::{AllowTypeChange, IntoPyArray, PyArray1, PyArray2, PyArrayLike1, PyUntypedArrayMethods};
use pyo3::exceptions::{PyKeyError, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyString};

use odocal::settings::ManifestSettings;
use odocal::sim::SimSidecar;
use odocal::{Drive, DriveBuilder, ExtraColumn, ExtraValues, Signals};

use crate::convert::{column, json, to_py, Column};
use crate::files::{check_outputs, warn_all};
use crate::lib_err;

/// Names of the drive columns `Drive.to_numpy()` returns, in order.
pub(crate) const COLUMNS: [&str; 8] = ["t", "px", "py", "psi", "n_rl", "n_rr", "beta", "a_y"];

/// Where a drive came from, beyond its samples: the simulator's sidecar
/// (true θ) and a manifest import's report. The CLI uses the same facts.
#[derive(Debug, Clone, Default)]
pub(crate) struct Provenance {
    /// The simulator sidecar (as for `drive.json` beside a CSV).
    pub(crate) sidecar: Option<SimSidecar>,
    /// The import report of a manifest, as JSON text.
    pub(crate) import_report: Option<String>,
    /// What one model revolution is (manifest imports).
    pub(crate) wheel_scale: Option<String>,
    /// The file the drive was read from (a CSV or a manifest), as given.
    pub(crate) source: Option<String>,
    /// `source` made absolute against the working directory of the read:
    /// the file the output checks protect wherever the process moves to.
    pub(crate) file: Option<PathBuf>,
}

impl Provenance {
    /// The manifest's calibration settings (`[noise]`, `[reference]`, `[calibration]`), read
    /// back from the import report (so they survive pickling with it).
    pub(crate) fn settings(&self) -> PyResult<Option<ManifestSettings>> {
        let Some(text) = &self.import_report else { return Ok(None) };
        let v: serde_json::Value =
            serde_json::from_str(text).map_err(|e| PyRuntimeError::new_err(format!("import report: {e}")))?;
        ManifestSettings::try_from(&v).map(Some).map_err(lib_err)
    }

    /// What the import of a manifest warned about, each as `source: warning`
    /// (the CLI's stderr lines and its JSON's `import_warnings`), read back
    /// from the import report; empty for other drives.
    pub(crate) fn import_warnings(&self) -> Vec<String> {
        let Some(text) = &self.import_report else { return Vec::new() };
        let v: serde_json::Value = serde_json::from_str(text).unwrap_or_default();
        let source = self.source.as_deref().unwrap_or("manifest");
        let warnings = v["warnings"].as_array().map(Vec::as_slice).unwrap_or_default();
        warnings.iter().filter_map(|w| w.as_str()).map(|w| format!("{source}: {w}")).collect()
    }
}

/// The provenance of each drive of a `drive` or `validate_on` argument (one
/// drive or a list of them), without joining them; empty for anything else.
pub(crate) fn provenances(v: &Bound<'_, PyAny>) -> Vec<Provenance> {
    if let Ok(d) = v.cast::<PyDrive>() {
        return vec![d.get().prov.clone()];
    }
    let Ok(items) = v.try_iter() else { return Vec::new() };
    items.filter_map(|x| x.ok()?.cast::<PyDrive>().ok().map(|d| d.get().prov.clone())).collect()
}

/// The first of `provs` (named by their files, or `what[i]`) that counts
/// wheel revolutions otherwise than `first` or the drives before it
/// ([`odocal::wheel_scale_mismatch`]): what differs.
pub(crate) fn wheel_scale_conflict(
    mut first: Option<(String, String)>,
    provs: &[Provenance],
    what: &str,
) -> Option<String> {
    provs.iter().enumerate().find_map(|(i, p)| {
        let name = p.source.clone().unwrap_or_else(|| format!("{what}[{i}]"));
        odocal::wheel_scale_mismatch(&mut first, &name, p.wheel_scale.as_deref())
    })
}

/// Adds `import_warnings` to a JSON report when the manifests of `provs`
/// warned, as `odocal calibrate --json` and `odocal validate --json` do.
pub(crate) fn with_import_warnings(v: &mut serde_json::Value, provs: &[Provenance]) {
    let imported: Vec<String> = provs.iter().flat_map(Provenance::import_warnings).collect();
    if let (Some(obj), false) = (v.as_object_mut(), imported.is_empty()) {
        obj.insert("import_warnings".into(), imported.into());
    }
}

/// One drive, or several of one vehicle joined with `Drive::concat`
/// (segments and parts never span two): the argument `drive` of
/// `calibrate` and `validate_on`. Returns the drive and each one's provenance.
pub(crate) fn drives_arg(v: &Bound<'_, PyAny>, what: &str) -> PyResult<(Arc<Drive>, Vec<Provenance>)> {
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
pub(crate) struct PyDrive {
    pub(crate) drive: Arc<Drive>,
    pub(crate) prov: Provenance,
}

impl PyDrive {
    pub(crate) fn new(drive: Drive, prov: Provenance) -> Self {
        PyDrive { drive: Arc::new(drive), prov }
    }
}

fn vec_f64(a: &Column<'_>) -> Vec<f64> {
    a.as_array().to_vec()
}

/// Most samples `Drive.from_arrays` copies (about 3.2 GB of columns; 350 h
/// at 40 Hz, 14 h at 1 kHz), and `Calibrator.push` and
/// `RawStream.push_messages` take in one call: checked before anything is
/// copied, so a huge array (or a view of one value broadcast, which takes
/// no memory until it is copied) raises instead of exhausting the memory.
const MAX_ARRAY_SAMPLES: usize = 50_000_000;

/// Every argument at most [`MAX_ARRAY_SAMPLES`] long, measured before
/// numpy converts any (an int32 array of 50 million samples would become
/// 400 MB of float64 per column first): `OdocalError` naming the argument
/// otherwise. The length is a numpy array's first dimension or Python's
/// `len()`; an argument without one is left to the conversion's errors
/// (unequal lengths are the library's error, after the copy). `holds`
/// names what would hold the samples and `advice` what to do instead.
pub(crate) fn check_array_lengths(
    args: &[(&str, Option<&Bound<'_, PyAny>>)],
    holds: &str,
    advice: &str,
) -> PyResult<()> {
    for (name, v) in args {
        let Some(v) = v else { continue };
        let len = match v.cast::<numpy::PyUntypedArray>() {
            Ok(a) => a.shape().first().copied(),
            Err(_) => v.len().ok(),
        };
        if let Some(n) = len.filter(|n| *n > MAX_ARRAY_SAMPLES) {
            return Err(crate::OdocalError::new_err(format!(
                "{name} has {n} samples, more than the {MAX_ARRAY_SAMPLES} {holds}; {advice}"
            )));
        }
    }
    Ok(())
}

/// The `part` argument of `Drive.from_arrays` as ids, read as the CSV's
/// `part` column is: integers (numpy's integer arrays as they are; floats
/// only when whole and within 0 … 10^15, else `OdocalError` naming the
/// sample). Negative ids are the library's error (`DriveBuilder`), as
/// for the CSV. Bools and anything else that is no number are refused.
fn part_ids(v: &Bound<'_, PyAny>, samples: (usize, &str)) -> PyResult<Vec<i64>> {
    crate::convert::refuse_masked("part", v, "sample")?;
    let array = v.py().import("numpy")?.call_method1("asarray", (v,))?;
    let kind: String = array.getattr("dtype")?.getattr("kind")?.extract()?;
    let not_an_id = |i: usize, id: String| {
        lib_err(odocal::Error::InvalidSample {
            context: ARRAYS.into(),
            column: "part".into(),
            sample: i,
            reason: format!("part id {id} is not a non-negative integer (parts are numbered 0, 1, 2, …)"),
        })
    };
    match kind.as_str() {
        "i" => {
            let ids: PyArrayLike1<'_, i64, AllowTypeChange> = column("part", &array, Some(samples))?;
            Ok(ids.as_array().to_vec())
        }
        // Unsigned ids beyond i64 would wrap to negative ones: named as they are.
        "u" => {
            let ids: PyArrayLike1<'_, u64, AllowTypeChange> = column("part", &array, Some(samples))?;
            ids.as_array()
                .iter()
                .enumerate()
                .map(|(i, id)| i64::try_from(*id).map_err(|_| not_an_id(i, id.to_string())))
                .collect()
        }
        "f" => {
            let ids: Column<'_> = column("part", &array, Some(samples))?;
            let ids = ids.as_array();
            if let Some(i) = ids.iter().position(|v| v.fract() != 0.0 || !(0.0..=1e15).contains(v)) {
                return Err(not_an_id(i, ids[i].to_string()));
            }
            Ok(ids.iter().map(|v| *v as i64).collect())
        }
        _ => Err(crate::OdocalError::new_err(format!(
            "part: got an array of numpy dtype {}, where integer part ids (0, 1, 2, …; a new part where the id \
             changes) are expected",
            array.getattr("dtype")?.str()?
        ))),
    }
}

/// How errors name a drive made from arrays.
const ARRAYS: &str = "numpy arrays";

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

/// A drive's loader for a CSV: the drive, the simulator sidecar beside it
/// when there is one that records the drive's fingerprint (as the CLI's
/// `calibrate` reads it), and the reader's warnings (a sidecar of another
/// drive among them).
fn read_csv_with_sidecar(path: &std::path::Path) -> odocal::Result<(Drive, Provenance, Vec<String>)> {
    let (drive, mut warnings) = Drive::read_csv(path)?;
    let (sidecar, note) = odocal::sim::SimSidecar::for_drive(path, &drive);
    warnings.extend(note);
    let source = Some(path.display().to_string());
    Ok((drive, Provenance { sidecar, source, file: absolute(path), ..Default::default() }, warnings))
}

fn read_manifest(path: &std::path::Path) -> odocal::Result<(Drive, Provenance)> {
    let m = odocal::Manifest::from_path(path)?;
    // The calibration settings are checked too, so a bad one is named now.
    ManifestSettings::try_from(&m)?;
    let (drive, report) = odocal::import(&m)?;
    let import_report = serde_json::to_string_pretty(&odocal::settings::import_report_json(&report)?)
        .map_err(|source| odocal::Error::Json { context: format!("import report of {}", path.display()), source })?;
    let wheel_scale = Some(report.wheel_scale.clone());
    let source = Some(path.display().to_string());
    let file = absolute(path);
    Ok((drive, Provenance { sidecar: None, import_report: Some(import_report), wheel_scale, source, file }))
}

/// `path` made absolute against the working directory now (not resolving
/// links); `None` when the working directory cannot be read.
fn absolute(path: &std::path::Path) -> Option<PathBuf> {
    std::path::absolute(path).ok()
}

#[pymethods]
impl PyDrive {
    /// Makes a drive from 1-D arrays (anything numpy converts to float64),
    /// checked by the library: equal lengths, finite values, strictly
    /// increasing and uniform time (within 1 % per part). `beta` defaults to
    /// zeros; `part` holds per-sample part ids, non-negative integers as
    /// the CSV's `part` column (a new part starts where the id changes);
    /// `sample_time_s` is the nominal step when known. An argument longer
    /// than 50,000,000 samples is refused before any is converted; a numpy
    /// masked array with masked values is refused (numpy would hand over
    /// the values under its mask).
    ///
    /// Raises `OdocalError` naming the column and the sample, or naming the
    /// argument, its shape and the 1-D array expected for one that is not
    /// 1-D (a 2-D array, a single number).
    #[staticmethod]
    #[pyo3(signature = (t, px, py, psi, n_rl, n_rr, a_y, beta=None, part=None, sample_time_s=None))]
    #[allow(clippy::too_many_arguments)]
    fn from_arrays(
        gil: Python<'_>,
        t: &Bound<'_, PyAny>,
        px: &Bound<'_, PyAny>,
        py: &Bound<'_, PyAny>,
        psi: &Bound<'_, PyAny>,
        n_rl: &Bound<'_, PyAny>,
        n_rr: &Bound<'_, PyAny>,
        a_y: &Bound<'_, PyAny>,
        beta: Option<&Bound<'_, PyAny>>,
        part: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = crate::convert::opt_real)] sample_time_s: Option<f64>,
    ) -> PyResult<Self> {
        // No argument longer than a drive from arrays may be, before numpy converts any.
        check_array_lengths(
            &[
                ("t", Some(t)),
                ("px", Some(px)),
                ("py", Some(py)),
                ("psi", Some(psi)),
                ("n_rl", Some(n_rl)),
                ("n_rr", Some(n_rr)),
                ("a_y", Some(a_y)),
                ("beta", beta),
                ("part", part),
            ],
            "a drive from arrays may hold",
            "split the drive",
        )?;
        // Each argument a 1-D array (else an error naming it and its shape), as long as t's.
        let t: Column<'_> = column("t", t, None)?;
        let n = Some((t.as_array().len(), "t"));
        let (px, py, psi): (Column<'_>, Column<'_>, Column<'_>) =
            (column("px", px, n)?, column("py", py, n)?, column("psi", psi, n)?);
        let (n_rl, n_rr, a_y): (Column<'_>, Column<'_>, Column<'_>) =
            (column("n_rl", n_rl, n)?, column("n_rr", n_rr, n)?, column("a_y", a_y, n)?);
        let beta: Option<Column<'_>> = beta.map(|b| column("beta", b, n)).transpose()?;
        let part = part.map(|p| part_ids(p, (t.as_array().len(), "t"))).transpose()?;
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
        let drive = gil
            .detach(move || {
                let b = DriveBuilder {
                    context: ARRAYS.into(),
                    t,
                    measured: signals,
                    part_ids: part,
                    sample_time_s,
                    ..Default::default()
                };
                b.build()
            })
            .map_err(lib_err)?;
        Ok(PyDrive::new(drive, Provenance::default()))
    }

    /// Reads a canonical CSV (docs/reference.md, "The drive CSV"). A simulator sidecar beside it
    /// (`drive.json` for `drive.csv`) that records this drive's fingerprint
    /// gives the true θ, as in the CLI; a sidecar of another drive is
    /// ignored with a `UserWarning`, as is a last line without a newline.
    #[staticmethod]
    fn from_csv(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let (drive, prov, warnings) = py.detach(|| read_csv_with_sidecar(&path)).map_err(lib_err)?;
        warn_all(py, &warnings)?;
        Ok(PyDrive::new(drive, prov))
    }

    /// Imports a multi-stream log described by a drive manifest (`.toml`).
    #[staticmethod]
    fn from_manifest(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let (drive, prov) = py.detach(|| read_manifest(&path)).map_err(lib_err)?;
        // What the import warned about (a corrupt row dropped, a clock offset not applied), as the CLI prints it.
        warn_all(py, &prov.import_warnings())?;
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
        let s = d.measured();
        let cols: [&[f64]; 8] = [d.t(), &s.px, &s.py, &s.psi, &s.n_rl, &s.n_rr, &s.beta, &s.a_y];
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
        if let Some(c) = d.extra().iter().find(|c| c.name == name).and_then(|c| match &c.values {
            odocal::ExtraValues::Numbers(v) => Some(v),
            odocal::ExtraValues::Text(_) => None,
        }) {
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

    /// The drive's fingerprint: SHA-256 (hex) of its canonical samples
    /// (time, the seven signals, parts and sample time), the same whether
    /// the drive was read from a CSV, imported through a manifest or made
    /// from arrays (the library's `Drive::fingerprint`).
    #[getter]
    fn fingerprint(&self, py: Python<'_>) -> String {
        let d = Arc::clone(&self.drive);
        py.detach(move || d.fingerprint())
    }

    /// The file the drive was read from (a CSV or a manifest), else None.
    #[getter]
    fn source(&self) -> Option<String> {
        self.prov.source.clone()
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
    /// (`drive.json` beside `drive.csv`), as `odocal simulate` does. Both
    /// are written atomically; a path that is one of the drive's own files
    /// (its CSV, manifest, stream files, sidecar) is refused, and so is a
    /// file beside `path` under the sidecar's name that is not a simulator
    /// sidecar.
    fn to_csv(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let side = odocal::sim::SimSidecar::path_beside(&path);
        let mut outputs = vec![("to_csv(path)", path.as_path())];
        if self.prov.sidecar.is_some() {
            if side == path {
                return Err(crate::OdocalError::new_err(format!(
                    "{}: the sidecar of a simulated drive is written beside the CSV under the name with .json, \
                     which is this file; give a name ending in .csv",
                    path.display()
                )));
            }
            outputs.push(("the sidecar to_csv writes beside path", side.as_path()));
            // The caller named the CSV, not the JSON beside it, which may be anything.
            if side.exists() && odocal::sim::SimSidecar::file_beside(&path).is_none() {
                return Err(crate::OdocalError::new_err(format!(
                    "{}: to_csv writes the simulated drive's sidecar (the truth) here, beside path under its name \
                     with .json, and this file is not a simulator sidecar; move it away or give path another name",
                    side.display()
                )));
            }
        }
        check_outputs(&[&self.prov], &outputs)?;
        let drive = Arc::clone(&self.drive);
        let sidecar = self.prov.sidecar.clone();
        py.detach(move || {
            drive.write_csv(&path)?;
            if let Some(s) = sidecar {
                s.write_beside(&path)?;
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
        state.set_item("source", self.prov.source.as_deref())?;
        state.set_item("file", self.prov.file.as_deref())?;
        let ctor = py.import("odocal._odocal")?.getattr("_drive_from_state")?;
        Ok((ctor, (state,)))
    }
}

/// Rebuilds a pickled drive (see `Drive.__reduce__`).
#[pyfunction]
pub(crate) fn _drive_from_state(py: Python<'_>, state: &Bound<'_, PyDict>) -> PyResult<PyDrive> {
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
        source: state.get_item("source")?.map(|s| s.extract()).transpose()?.flatten(),
        file: state.get_item("file")?.map(|s| s.extract()).transpose()?.flatten(),
    };
    let drive = py
        .detach(move || {
            let b = DriveBuilder {
                context: "pickled drive".into(),
                t,
                measured,
                truth,
                reference_measured: ref_measured,
                extra,
                parts: Some(parts),
                sample_time_s: Some(ts),
                ..Default::default()
            };
            b.build()
        })
        .map_err(lib_err)?;
    Ok(PyDrive::new(drive, prov))
}
