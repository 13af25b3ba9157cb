//! `odocal.online.Calibrator`: the library's online calibrator
//! ([`odocal_online::Calibrator`]) fed with numpy arrays, and its
//! write-back gates ([`odocal_online::gate::Gates`]).

use std::sync::{Mutex, MutexGuard};

use numpy::PyArray2;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use serde::de::DeserializeOwned;
use serde::Serialize;

use odocal::{Signals, Theta};
use odocal_online::gate::Gates;
use odocal_online::{Calibrator, OnlineOptions};

use crate::convert::{column, extract_sigma, extract_theta, json, to_json, to_py, Column};
use crate::drive::PyDrive;
use crate::{lib_err, OdocalError};

/// `defaults` (a library options struct) with the keys of `given` put over
/// it, nested tables key by key; an unknown key raises `TypeError` naming it
/// and the known ones; a bad value, `OdocalError` with serde's message.
pub(crate) fn overlay<T: Serialize + DeserializeOwned>(
    defaults: &T,
    given: Option<&Bound<'_, PyDict>>,
    what: &str,
) -> PyResult<T> {
    let mut v = json(defaults)?;
    if let Some(d) = given {
        merge(&mut v, to_json(d.as_any(), what)?, what)?;
    }
    serde_json::from_value(v)
        .map_err(|e| lib_err(odocal::Error::InvalidOption { field: "options", reason: format!("{what}: {e}") }))
}

fn merge(base: &mut serde_json::Value, given: serde_json::Value, path: &str) -> PyResult<()> {
    use serde_json::Value;
    let (Value::Object(b), Value::Object(g)) = (&mut *base, &given) else {
        *base = given;
        return Ok(());
    };
    for (k, x) in g {
        let Some(slot) = b.get_mut(k) else {
            let known: Vec<&str> = b.keys().map(String::as_str).collect();
            return Err(PyTypeError::new_err(format!("{path}: no option '{k}' (known: {})", known.join(", "))));
        };
        if slot.is_object() && x.is_object() {
            merge(slot, x.clone(), &format!("{path}.{k}"))?;
        } else {
            *slot = x.clone();
        }
    }
    Ok(())
}

/// The online calibrator: a recursive Gauss-Newton over the calibration
/// segments of a stream of samples. One thread at a time uses it: a call
/// from another thread while a push runs (without the GIL) waits for it.
#[pyclass(module = "odocal.online", name = "Calibrator", frozen)]
pub(crate) struct PyCalibrator {
    cal: Mutex<Calibrator>,
    gates: Gates,
}

/// The calibrator behind `cal`, locked (a push holds it without the GIL).
fn lock(cal: &Mutex<Calibrator>) -> PyResult<MutexGuard<'_, Calibrator>> {
    crate::lock(cal, "calibrator")
}

impl PyCalibrator {
    /// The calibrator's status now.
    fn status(&self) -> PyResult<odocal_online::Status> {
        Ok(lock(&self.cal)?.status())
    }
}

#[pymethods]
impl PyCalibrator {
    /// A calibrator starting at `theta0` (default: the paper's initial θ)
    /// with sd `sigma0` (default: the options' prior) for samples every
    /// `sample_time_s` seconds. Other keywords are the library's
    /// `OnlineOptions` fields (nested ones as dicts: `random_walk={"c_e_relative": 1e-3}`);
    /// `gates` is a dict of the write-back gates' fields.
    #[new]
    #[pyo3(signature = (theta0=None, sigma0=None, sample_time_s=0.025, *, gates=None, **options))]
    fn new(
        theta0: Option<&Bound<'_, PyAny>>,
        sigma0: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = crate::convert::real)] sample_time_s: f64,
        gates: Option<&Bound<'_, PyDict>>,
        options: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let theta0 = theta0.map(extract_theta).transpose()?.unwrap_or(Theta::PAPER_INITIAL);
        let sigma0 = sigma0.map(|s| extract_sigma(s, "sigma0")).transpose()?;
        let opts: OnlineOptions = overlay(&OnlineOptions::default(), options, "options")?;
        let gates: Gates = overlay(&Gates::default(), gates, "gates")?;
        let cal = Calibrator::new(theta0, sigma0, sample_time_s, opts).map_err(lib_err)?;
        Ok(PyCalibrator { cal: Mutex::new(cal), gates })
    }

    /// Takes the next samples of the current drive, in time order: the
    /// columns of `Drive.from_arrays` (`beta` defaults to zeros; `psi` is
    /// unwrapped across chunks). With `t`, each step must be the sample
    /// time (within 1 %), or a gap of more than 1.5 sample times, after
    /// which a new continuous part starts; without it, the samples follow
    /// the previous ones. Raises `OdocalError` for columns of different
    /// lengths, values that are not finite, times that do not fit, an
    /// argument that is not 1-D (naming it and its shape), or one of more
    /// than 50,000,000 samples (before any is converted: push in chunks).
    #[pyo3(signature = (t, px, py, psi, n_rl, n_rr, a_y, beta=None))]
    #[allow(clippy::too_many_arguments)] // one argument per column, as Drive.from_arrays
    fn push(
        &self,
        gil: Python<'_>,
        t: Option<&Bound<'_, PyAny>>,
        px: &Bound<'_, PyAny>,
        py: &Bound<'_, PyAny>,
        psi: &Bound<'_, PyAny>,
        n_rl: &Bound<'_, PyAny>,
        n_rr: &Bound<'_, PyAny>,
        a_y: &Bound<'_, PyAny>,
        beta: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        // No argument longer than one push takes, before numpy converts any.
        let args = [("t", t), ("px", Some(px)), ("py", Some(py)), ("psi", Some(psi))];
        let more = [("n_rl", Some(n_rl)), ("n_rr", Some(n_rr)), ("a_y", Some(a_y)), ("beta", beta)];
        let (holds, advice) = ("one push takes", "push the samples in chunks");
        crate::drive::check_array_lengths(&[args.as_slice(), more.as_slice()].concat(), holds, advice)?;
        // Each argument a 1-D array (else an error naming it and its shape), as long as px's.
        let px: Column<'_> = column("px", px, None)?;
        let n = px.as_array().len();
        let k = Some((n, "px"));
        let t: Option<Column<'_>> = t.map(|t| column("t", t, k)).transpose()?;
        let (py, psi, n_rl): (Column<'_>, Column<'_>, Column<'_>) =
            (column("py", py, k)?, column("psi", psi, k)?, column("n_rl", n_rl, k)?);
        let (n_rr, a_y): (Column<'_>, Column<'_>) = (column("n_rr", n_rr, k)?, column("a_y", a_y, k)?);
        let beta: Option<Column<'_>> = beta.map(|b| column("beta", b, k)).transpose()?;
        let col = |c: Column<'_>| c.as_array().to_vec();
        let beta = beta.map_or_else(|| vec![0.0; n], col);
        let samples =
            Signals { px: col(px), py: col(py), psi: col(psi), n_rl: col(n_rl), n_rr: col(n_rr), beta, a_y: col(a_y) };
        let t = t.map(col);
        let cal = &self.cal;
        gil.detach(|| lock(cal)?.push(t.as_deref(), &samples).map_err(lib_err))
    }

    /// Pushes a whole `odocal.Drive` as a new drive, part by part, in
    /// chunks of `chunk` samples (what `odocal follow` does).
    #[pyo3(signature = (drive, chunk=400))]
    fn push_drive(
        &self,
        gil: Python<'_>,
        drive: &Bound<'_, PyDrive>,
        #[pyo3(from_py_with = crate::convert::count)] chunk: usize,
    ) -> PyResult<()> {
        let d = std::sync::Arc::clone(&drive.get().drive);
        let ts = self.status()?.sample_time_s;
        if (d.sample_time_s() - ts).abs() > 1e-9 {
            return Err(OdocalError::new_err(format!(
                "the drive's sample time {} s is not the calibrator's {} s",
                d.sample_time_s(),
                ts
            )));
        }
        let cal = &self.cal;
        gil.detach(|| lock(cal)?.push_drive(&d, chunk, |_| {}).map_err(lib_err))
    }

    /// Starts a new drive: the heading offset starts anew, the drive's
    /// counters are cleared; θ and its covariance carry over.
    fn new_drive(&self) -> PyResult<()> {
        lock(&self.cal)?.begin_drive();
        Ok(())
    }

    /// Starts a new continuous part of the current drive (after a gap that
    /// `t` does not show).
    fn new_part(&self) -> PyResult<()> {
        lock(&self.cal)?.begin_part();
        Ok(())
    }

    /// The current θ: `{"c_e", "c_d", "t_r", "d"}`.
    #[getter]
    fn theta<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &json(&self.status()?.theta)?)
    }

    /// θ's standard deviation, same keys.
    #[getter]
    fn sigma<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &json(&self.status()?.sigma)?)
    }

    /// The 5×5 covariance of `[c_e, c_d, t_r, d, heading_offset]`.
    #[getter]
    fn covariance<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let rows: Vec<Vec<f64>> = self.status()?.covariance.iter().map(|r| r.to_vec()).collect();
        Ok(PyArray2::from_vec2(py, &rows)?)
    }

    /// The current drive's heading offset (reference minus vehicle) and its sd, rad.
    #[getter]
    fn heading_offset(&self) -> PyResult<(f64, f64)> {
        let s = self.status()?;
        Ok((s.heading_offset_rad, s.heading_offset_sd_rad))
    }

    /// The sample time the calibrator was made for, s.
    #[getter]
    fn sample_time_s(&self) -> PyResult<f64> {
        Ok(self.status()?.sample_time_s)
    }

    /// Informative (turning) driving folded in so far, s.
    #[getter]
    fn informative_time_s(&self) -> PyResult<f64> {
        Ok(self.status()?.informative_time_s)
    }

    /// Samples held in the buffer (bounded, whatever the drive's length).
    #[getter]
    fn buffered_samples(&self) -> PyResult<usize> {
        Ok(self.status()?.buffered_samples)
    }

    /// What the calibrator saw of the current drive: `samples`,
    /// `folded_segments`, `validation_segments`,
    /// `prequential_mean_position_error_m`, `stored_mean_position_error_m`.
    #[getter]
    fn summary<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &json(&self.status()?.drive)?)
    }

    /// The drive's most recently scored validation segments, oldest first:
    /// dicts with `start_s`, `prequential_m`, `stored_m`.
    #[getter]
    fn recent_validation<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &json(&self.status()?.recent_validation)?)
    }

    /// θ from the current drive's folded segments alone, without the prior
    /// carried from earlier drives (what the gates compare the estimate
    /// with): `{"theta": {...}, "sigma": {...}}`, `sigma` scaled as the
    /// calibrator's; `None` until the drive determines every parameter.
    #[getter]
    fn drive_estimate<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &json(&self.status()?.drive_estimate)?)
    }

    /// The parameters in use, compared with the online θ on each
    /// validation segment and by the gates (`None`: none).
    #[getter]
    fn get_stored<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let stored = lock(&self.cal)?.stored;
        to_py(py, &json(&stored)?)
    }

    #[setter]
    fn set_stored(&self, theta: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
        let theta = theta.filter(|t| !t.is_none()).map(extract_theta).transpose()?;
        lock(&self.cal)?.stored = theta;
        Ok(())
    }

    /// The write-back gates' thresholds, as a dict.
    #[getter]
    fn gates<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &json(&self.gates)?)
    }

    /// The gates' decision on the current estimate against `stored`
    /// (default: the stored θ): `{"action": "write" | "hold" | "flag",
    /// "reasons": [...], "theta": {...}, "sigma": {...}}`. `calibrated`:
    /// `stored` is a recorded calibration (else an initial guess, which
    /// does not bound the change).
    #[pyo3(signature = (stored=None, calibrated=true))]
    fn decide<'py>(
        &self,
        py: Python<'py>,
        stored: Option<&Bound<'_, PyAny>>,
        calibrated: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let given = stored.map(extract_theta).transpose()?;
        let cal = lock(&self.cal)?;
        let stored = given
            .or(cal.stored)
            .ok_or_else(|| OdocalError::new_err("no stored θ: give stored= or set calibrator.stored first"))?;
        let decision = json(&self.gates.decide(&cal, &stored, calibrated))?;
        drop(cal);
        to_py(py, &decision)
    }

    fn __repr__(&self) -> PyResult<String> {
        let s = self.status()?;
        Ok(format!("<odocal.online.Calibrator {}>", s.theta.display_with_sigma(&s.sigma)))
    }
}
