//! `odocal.online.RawStream`: the library's streamed import
//! ([`odocal::io::RawStream`]) fed message by message from Python, its
//! canonical samples taken as numpy arrays.

use std::sync::{Mutex, MutexGuard};

use numpy::IntoPyArray;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use odocal::io::RawStream;
use odocal::Manifest;

use crate::convert::{column, json, not_an_array_of, table, to_py, Column};
use crate::lib_err;

/// The import of a manifest's streams as their messages arrive: canonical
/// samples come out once every stream has passed their time. One thread at
/// a time uses it: a call from another thread while a push runs (without
/// the GIL) waits for it.
#[pyclass(module = "odocal.online", name = "RawStream", frozen)]
pub(crate) struct PyRawStream {
    state: Mutex<State>,
    manifest: Manifest,
}

/// What a [`PyRawStream`] changes as messages arrive.
struct State {
    raw: RawStream,
    /// The import report, once `finish()` returned it.
    report: Option<odocal::ImportReport>,
}

/// The state behind `state`, locked (a push holds it without the GIL).
fn lock(state: &Mutex<State>) -> PyResult<MutexGuard<'_, State>> {
    crate::lock(state, "stream")
}

#[pymethods]
impl PyRawStream {
    /// The streamed import of the manifest at `manifest` (its streams are
    /// pushed, not read), the clock offset estimated on the first
    /// `warm_up_s` seconds of the wheel stream (None: the library's 300 s).
    /// Raises `OdocalError` for a manifest that is not streamed (the reason
    /// named) or a bad warm-up.
    #[new]
    #[pyo3(signature = (manifest, *, warm_up_s=None))]
    fn new(
        manifest: std::path::PathBuf,
        #[pyo3(from_py_with = crate::convert::opt_real)] warm_up_s: Option<f64>,
    ) -> PyResult<Self> {
        let m = Manifest::from_path(&manifest).map_err(lib_err)?;
        let raw = RawStream::new(&m, warm_up_s).map_err(lib_err)?;
        Ok(PyRawStream { state: Mutex::new(State { raw, report: None }), manifest: m })
    }

    /// The streams the manifest reads: for each name, its `file`,
    /// `time_column` and the `columns` each message carries, in the order
    /// `push_message` takes its values.
    #[getter]
    fn streams<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let out = PyDict::new(py);
        let files = self.manifest.stream_files();
        for (name, time_column, cols) in lock(&self.state)?.raw.columns() {
            let d = PyDict::new(py);
            d.set_item("file", files.iter().find(|(n, _)| n == name).map(|(_, f)| f))?;
            d.set_item("time_column", time_column)?;
            d.set_item("columns", cols.to_vec())?;
            out.set_item(name, d)?;
        }
        Ok(out)
    }

    /// One message of stream `stream`: its time `t` in the stream's
    /// `time_unit` (before `time_offset_s`) and the values of its columns
    /// (`streams[stream]["columns"]`). Messages of one stream come in time
    /// order. Raises `OdocalError` naming the stream (an unknown one, a
    /// wrong number of values) or the row and column (the whole import's
    /// checks of the rows), or naming `values` and its shape when it is not
    /// a 1-D sequence of numbers.
    fn push_message(&self, py: Python<'_>, stream: &str, t: f64, values: &Bound<'_, PyAny>) -> PyResult<()> {
        let values: Vec<f64> = values.extract().map_err(|e| {
            let expected = "a 1-D sequence of the stream's column values (streams[stream][\"columns\"])";
            not_an_array_of("values", values, 1, expected, &e)
        })?;
        let state = &self.state;
        py.detach(|| lock(state)?.raw.push_message(stream, t, &values).map_err(lib_err))
    }

    /// Several messages of stream `stream` at once: times `t` (n, 1-D) and
    /// `values` (n × columns, 2-D; anything numpy converts to float64), as
    /// `push_message` one by one. Another shape raises `OdocalError`
    /// naming the argument and its shape, and so does an argument of more
    /// than 50,000,000 messages (before any is converted).
    fn push_messages(
        &self,
        py: Python<'_>,
        stream: &str,
        t: &Bound<'_, PyAny>,
        values: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        // No more messages than one call takes, before numpy converts any.
        let (holds, advice) = ("one call takes", "push the messages in chunks");
        crate::drive::check_array_lengths(&[("t", Some(t)), ("values", Some(values))], holds, advice)?;
        // A 1-D t and a 2-D values (else an error naming the argument and its shape).
        let t: Column<'_> = column("t", t, None)?;
        let t = t.as_array().to_vec();
        let v = table("values", values, t.len())?;
        if v.nrows() != t.len() {
            return Err(lib_err(odocal::Error::InvalidOption {
                field: "values",
                reason: format!("{} rows of values for {} times (stream '{stream}')", v.nrows(), t.len()),
            }));
        }
        let state = &self.state;
        py.detach(|| {
            let raw = &mut lock(state)?.raw;
            for (i, ti) in t.iter().enumerate() {
                raw.push_message(stream, *ti, &v.row(i).to_vec()).map_err(lib_err)?;
            }
            Ok(())
        })
    }

    /// No more messages of `stream` come.
    fn end_stream(&self, stream: &str) -> PyResult<()> {
        lock(&self.state)?.raw.end_stream(stream).map_err(lib_err)
    }

    /// Ends every stream and the drive: the last samples become ready and
    /// `report` is set. Raises `OdocalError` for the whole import's errors
    /// about the drive (streams that do not overlap, no part long enough).
    fn finish(&self, py: Python<'_>) -> PyResult<()> {
        let state = &self.state;
        py.detach(|| {
            let mut s = lock(state)?;
            let report = s.raw.finish().cloned().map_err(lib_err)?;
            s.report = Some(report);
            Ok(())
        })
    }

    /// Up to `max` ready samples of one part, oldest first, or None: a dict
    /// with `part`, `start` (the index of the first among the drive's
    /// samples), `starts_part`, `reference_measured` (bool array) and
    /// `samples`, a dict of arrays `t`, `px`, `py`, `psi`, `n_rl`, `n_rr`,
    /// `a_y`, `beta`: the arguments of `Calibrator.push`. `max` is an
    /// integer of at least 1; another raises `OdocalError`.
    #[pyo3(signature = (max=400))]
    fn take_chunk<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = crate::convert::count)] max: usize,
    ) -> PyResult<Option<Bound<'py, PyDict>>> {
        if max == 0 {
            return Err(lib_err(odocal::Error::InvalidOption {
                field: "max",
                reason: "take_chunk(max) takes at least 1 sample, got 0".into(),
            }));
        }
        let Some(c) = lock(&self.state)?.raw.take_chunk(max) else { return Ok(None) };
        let d = PyDict::new(py);
        d.set_item("part", c.part)?;
        d.set_item("start", c.start)?;
        d.set_item("starts_part", c.starts_part)?;
        let measured = c.reference_measured.unwrap_or_else(|| vec![true; c.t.len()]);
        d.set_item("reference_measured", measured.into_pyarray(py))?;
        let s = PyDict::new(py);
        let g = c.signals;
        s.set_item("t", c.t.into_pyarray(py))?;
        for (name, col) in [
            ("px", g.px),
            ("py", g.py),
            ("psi", g.psi),
            ("n_rl", g.n_rl),
            ("n_rr", g.n_rr),
            ("a_y", g.a_y),
            ("beta", g.beta),
        ] {
            s.set_item(name, col.into_pyarray(py))?;
        }
        d.set_item("samples", s)?;
        Ok(Some(d))
    }

    /// The clock offset once the warm-up is over (a dict, as in the import
    /// report), else None.
    #[getter]
    fn clock_offset<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let offset = lock(&self.state)?.raw.clock_offset().map(json).transpose()?;
        offset.map(|c| to_py(py, &c)).transpose()
    }

    /// The import report after `finish()` (a dict of the library's
    /// `ImportReport`), else None.
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let report = lock(&self.state)?.report.as_ref().map(json).transpose()?;
        report.map(|r| to_py(py, &r)).transpose()
    }

    /// Rows and samples the import holds now.
    #[getter]
    fn held(&self) -> PyResult<usize> {
        Ok(lock(&self.state)?.raw.held())
    }
}
