//! Values between Python and the library: JSON reports as Python objects,
//! Python values as JSON (keyword options, θ), parameter-file paths.

use pyo3::exceptions::{PyRuntimeError, PyTypeError};
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString};

use odocal::model::Theta;

use crate::{lib_err, OdocalError};

/// A value serialised for Python (through [`to_py`]).
pub(crate) fn json<T: serde::Serialize>(v: &T) -> PyResult<serde_json::Value> {
    serde_json::to_value(v).map_err(|e| PyRuntimeError::new_err(format!("serialising a report: {e}")))
}

/// A JSON value as plain Python objects (dict, list, str, int, float, bool,
/// None), the same as `json.loads` of its text.
pub(crate) fn to_py<'py>(py: Python<'py>, v: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
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

/// A float as JSON, which has no NaN or infinity.
fn float(f: f64, what: &str) -> PyResult<serde_json::Value> {
    serde_json::Number::from_f64(f)
        .map(serde_json::Value::Number)
        .ok_or_else(|| OdocalError::new_err(format!("{what}: {f} is not a finite number")))
}

/// A Python value as JSON, as the library reads keyword options: None,
/// bool, int, float, str, a path (`os.PathLike`), a dict with str keys, or
/// any other iterable (list, tuple, numpy array) as a list. `what` names
/// the value in the error for anything else.
pub(crate) fn to_json(v: &Bound<'_, PyAny>, what: &str) -> PyResult<serde_json::Value> {
    use serde_json::Value;
    if v.is_none() {
        return Ok(Value::Null);
    }
    if let Ok(b) = v.cast::<PyBool>() {
        return Ok(Value::Bool(b.is_true()));
    }
    if let Ok(s) = v.cast::<PyString>() {
        return Ok(Value::String(s.to_str()?.to_string()));
    }
    if let Ok(d) = v.cast::<PyDict>() {
        let mut m = serde_json::Map::new();
        for (k, x) in d.iter() {
            let key: String =
                k.extract().map_err(|_| PyTypeError::new_err(format!("{what}: a dict's keys must be text")))?;
            m.insert(key, to_json(&x, what)?);
        }
        return Ok(Value::Object(m));
    }
    if let Ok(f) = v.cast::<PyFloat>() {
        return float(f.value(), what);
    }
    // A complex number (Python's or numpy's) is no real number: its
    // imaginary part would be dropped silently.
    if v.cast::<pyo3::types::PyComplex>().is_ok() || v.get_type().name()?.to_str()?.starts_with("complex") {
        return Err(PyTypeError::new_err(format!("{what}: a complex number is not a real number")));
    }
    // Integers (also numpy's, through `__index__`), then other floats (numpy's).
    if let Ok(i) = v.extract::<i64>() {
        return Ok(i.into());
    }
    if let Ok(u) = v.extract::<u64>() {
        return Ok(u.into());
    }
    if v.cast::<PyInt>().is_ok() {
        // Beyond 64 bits: as a float it would lose its digits unnoticed.
        return Err(OdocalError::new_err(format!(
            "{what}: {v} is beyond the integers odocal takes (−2^63 … 2^64 − 1)"
        )));
    }
    if let Ok(f) = v.extract::<f64>() {
        return float(f, what);
    }
    if v.hasattr("__fspath__")? {
        let path = v.py().import("os")?.call_method1("fspath", (v,))?;
        return to_json(&path, what);
    }
    match v.try_iter() {
        Ok(items) => Ok(Value::Array(items.map(|x| to_json(&x?, what)).collect::<PyResult<_>>()?)),
        Err(_) => Err(PyTypeError::new_err(format!(
            "{what}: cannot take a {} (give None, a bool, number, text, path, dict or list)",
            v.get_type().name()?
        ))),
    }
}

/// The parameter file a θ argument names: a text ending in `.yaml`, `.yml`
/// or `.json` (the Python layer turns path objects into text), read by the
/// library at the node `node` (`params_node=`; `None`: the one node with
/// odocal's parameters); `None` for any other argument.
pub(crate) fn params_file_arg(v: &Bound<'_, PyAny>, node: Option<&str>) -> PyResult<Option<odocal::ParamFile>> {
    let Ok(s) = v.cast::<PyString>() else { return Ok(None) };
    let path = std::path::Path::new(s.to_str()?);
    if odocal::ParamFile::is_param_file(path) {
        return odocal::ParamFile::read(path, node).map(Some).map_err(lib_err);
    }
    Ok(None)
}

/// θ from a dict `{"c_e", "c_d", "t_r", "d"}`, a sequence of four numbers,
/// the CLI's text `"c_e,c_d,t_r,d"` or the path of a parameter file
/// (`--params-out`'s), read and checked by the library as the `theta0`
/// setting is.
pub(crate) fn extract_theta(v: &Bound<'_, PyAny>) -> PyResult<Theta> {
    let json = to_json(v, "θ")?;
    if let Some(at) = theta_bool(&json) {
        return Err(PyTypeError::new_err(format!(
            "θ: {at} is a bool, not a number (True and False are not values of θ); give numbers"
        )));
    }
    odocal::Theta::try_from(json).map_err(lib_err)
}

/// The σ of θ (`sigma0=`): a dict `{"c_e", "c_d", "t_r", "d"}` or four
/// numbers, each finite and not negative; no physical limits (a σ is
/// small). `OdocalError` naming a key other than the four, a missing one
/// or a bad value.
pub(crate) fn extract_sigma(v: &Bound<'_, PyAny>, what: &str) -> PyResult<Theta> {
    let json = to_json(v, what)?;
    if let Some(at) = theta_bool(&json) {
        return Err(PyTypeError::new_err(format!("{what}: {at} is a bool, not a number; give numbers")));
    }
    sigma_from_json(json, what)
}

/// [`extract_sigma`] of a value already JSON.
fn sigma_from_json(json: serde_json::Value, what: &str) -> PyResult<Theta> {
    use serde_json::Value;
    const NAMES: [&str; 4] = ["c_e", "c_d", "t_r", "d"];
    let values: Vec<Value> = match json {
        Value::Array(a) if a.len() == 4 => a,
        Value::Object(mut m) => {
            if let Some(k) = m.keys().find(|k| !NAMES.contains(&k.as_str())) {
                return Err(OdocalError::new_err(format!("{what}: unknown key '{k}': σ has c_e, c_d, t_r and d")));
            }
            let values = NAMES.iter().map(|n| m.remove(*n).ok_or(*n)).collect::<Result<Vec<_>, _>>();
            values.map_err(|n| OdocalError::new_err(format!("{what}: missing {n}: σ has c_e, c_d, t_r and d")))?
        }
        other => {
            return Err(OdocalError::new_err(format!(
                "{what}: got {other}, where a dict of c_e, c_d, t_r, d or four numbers is expected"
            )))
        }
    };
    let mut sd = [0.0; 4];
    for (i, x) in values.iter().enumerate() {
        match x.as_f64() {
            Some(f) if f >= 0.0 => sd[i] = f,
            _ => {
                return Err(OdocalError::new_err(format!(
                    "{what}: {} = {x}: a standard deviation is a finite number, not negative",
                    NAMES[i]
                )))
            }
        }
    }
    Ok(Theta::from(sd))
}

/// Where θ's JSON holds a bool: `c_e = True` (a dict's key or a list's
/// place) or the value itself; `None` without one.
fn theta_bool(v: &serde_json::Value) -> Option<String> {
    use serde_json::Value;
    const NAMES: [&str; 4] = ["c_e", "c_d", "t_r", "d"];
    let py = |b: bool| if b { "True" } else { "False" };
    match v {
        Value::Bool(b) => Some(py(*b).to_string()),
        Value::Array(a) => a.iter().enumerate().find_map(|(i, x)| {
            let b = x.as_bool()?;
            Some(format!("{} = {} (item {i})", NAMES.get(i).unwrap_or(&"?"), py(b)))
        }),
        Value::Object(m) => m.iter().find_map(|(k, x)| Some(format!("{k} = {}", py(x.as_bool()?)))),
        _ => None,
    }
}

/// A keyword option's value that holds a bool where the setting `key`
/// takes a number: a `TypeError` naming the key (a bool is an int to
/// Python, so `bootstrap=True` would otherwise mean 1). Bools of boolean
/// settings pass.
pub(crate) fn refuse_bool_for_number(key: &str, value: &serde_json::Value) -> PyResult<()> {
    let has_bool = match value {
        serde_json::Value::Bool(_) => true,
        serde_json::Value::Array(a) => a.iter().any(|x| x.as_bool().is_some()),
        _ => false,
    };
    if !has_bool {
        return Ok(());
    }
    let alone = serde_json::json!({ key: value });
    if odocal::settings::Settings::try_from(alone).is_ok() {
        return Ok(());
    }
    Err(PyTypeError::new_err(format!(
        "{key}: {value} holds a bool where a number is expected (True and False are not numbers here)"
    )))
}

/// Refuses a Python bool where a number is asked for: `True` is an `int`
/// to Python, so `threads=True` would otherwise mean one thread.
fn not_bool(v: &Bound<'_, PyAny>) -> PyResult<()> {
    if v.is_instance_of::<PyBool>() {
        return Err(PyTypeError::new_err(format!("a number is needed here, not the bool {v}")));
    }
    Ok(())
}

/// A count argument (`substeps=`, `chunk=`, …): an int, not a bool.
pub(crate) fn count(v: &Bound<'_, PyAny>) -> PyResult<usize> {
    not_bool(v)?;
    v.extract().map_err(|e| out_of_range(v, "a count is an integer 0 … 2^64 − 1", e))
}

/// An int where another range of ints is asked for (negative, or beyond
/// 64 bits): `OdocalError` saying what is asked for (`range`), where the
/// conversion's own error is an `OverflowError` ("can't convert negative
/// int to unsigned"). Anything else keeps the conversion's error `e`.
fn out_of_range(v: &Bound<'_, PyAny>, range: &str, e: PyErr) -> PyErr {
    if v.cast::<PyInt>().is_ok() || v.extract::<i64>().is_ok() {
        return OdocalError::new_err(format!("{range}, got {v}"));
    }
    e
}

/// An optional count argument: None, or an int that is not a bool.
pub(crate) fn opt_count(v: &Bound<'_, PyAny>) -> PyResult<Option<usize>> {
    if v.is_none() {
        return Ok(None);
    }
    count(v).map(Some)
}

/// The `threads=` argument: None (all cores) or 1 … `MAX_THREADS`, an
/// int that is not a bool; `OdocalError` for another int.
pub(crate) fn opt_threads(v: &Bound<'_, PyAny>) -> PyResult<Option<usize>> {
    if v.is_none() {
        return Ok(None);
    }
    not_bool(v)?;
    let max = odocal::settings::MAX_THREADS;
    let range = format!("threads is a number of worker threads, 1 … {max}");
    match v.extract::<usize>() {
        Ok(n) if (1..=max).contains(&n) => Ok(Some(n)),
        Ok(n) => Err(OdocalError::new_err(format!("{range}, got {n}"))),
        Err(e) => Err(out_of_range(v, &range, e)),
    }
}

/// What a seed is, for messages (the library's words for `seed=` of
/// `calibrate`).
const SEED_RANGE: &str = "a seed, an integer 0 … 2^64 − 1 (18446744073709551615)";

/// A seed (`seed=` of `simulate` and `calibrate`, `bootstrap_seed=`;
/// `key` names it): an int 0 … 2^64 − 1 that is not a bool.
/// `OdocalError` for another number, saying the range.
pub(crate) fn seed_of(v: &Bound<'_, PyAny>, key: &str) -> PyResult<u64> {
    if v.is_instance_of::<PyBool>() {
        return Err(PyTypeError::new_err(format!("{key}: a number is needed here, not the bool {v}")));
    }
    v.extract().map_err(|e| {
        if v.cast::<PyInt>().is_ok() || v.extract::<f64>().is_ok() {
            OdocalError::new_err(format!("{key} = {v} is not {SEED_RANGE}"))
        } else {
            e
        }
    })
}

/// The `seed=` argument of `simulate`.
pub(crate) fn seed(v: &Bound<'_, PyAny>) -> PyResult<u64> {
    seed_of(v, "seed")
}

/// A real-number argument: an int or float, not a bool (nor a complex).
pub(crate) fn real(v: &Bound<'_, PyAny>) -> PyResult<f64> {
    not_bool(v)?;
    v.extract()
}

/// An optional real-number argument: None, or `real`.
pub(crate) fn opt_real(v: &Bound<'_, PyAny>) -> PyResult<Option<f64>> {
    if v.is_none() {
        return Ok(None);
    }
    real(v).map(Some)
}

/// A float64 column, as numpy hands it over.
pub(crate) type Column<'py> = numpy::PyArrayLike1<'py, f64, numpy::AllowTypeChange>;

/// A column argument `name` (one value per sample): anything numpy makes a
/// 1-D array of `T` from. Anything else (a 2-D array, a single number,
/// text) raises `OdocalError` naming the argument, what it got (its type
/// and numpy's shape) and what is expected: a 1-D array, of `samples`
/// samples when the length is known from an earlier column (`first`).
pub(crate) fn column<'py, T>(
    name: &str,
    v: &Bound<'py, PyAny>,
    samples: Option<(usize, &str)>,
) -> PyResult<numpy::PyArrayLike1<'py, T, numpy::AllowTypeChange>>
where
    T: numpy::Element,
    for<'a> numpy::PyArrayLike1<'py, T, numpy::AllowTypeChange>: FromPyObject<'a, 'py, Error = PyErr>,
{
    refuse_masked(name, v, "sample")?;
    let e = match v.extract() {
        Ok(a) => return Ok(a),
        Err(e) => e,
    };
    let expected = match samples {
        Some((n, first)) => format!("a 1-D array of {n} samples (one value per sample, as {first})"),
        None => "a 1-D array (one value per sample)".to_string(),
    };
    Err(not_an_array_of(name, v, 1, &expected, &e))
}

/// Refuses a numpy masked array (`numpy.ma`) with masked values as the
/// argument `name`: numpy converts it to the values under the mask, which
/// would be taken as data. `OdocalError` naming how many are masked and
/// the first (`unit`: "sample" of a column, "row" of a table).
pub(crate) fn refuse_masked(name: &str, v: &Bound<'_, PyAny>, unit: &str) -> PyResult<()> {
    let py = v.py();
    // numpy.ma is imported with numpy; a module not loaded means no masked array.
    let Some(ma) = py.import("sys")?.getattr("modules")?.get_item("numpy.ma").ok() else { return Ok(()) };
    if !v.is_instance(&ma.getattr("MaskedArray")?)? {
        return Ok(());
    }
    let masked = py.import("numpy")?.call_method1("argwhere", (ma.call_method1("getmaskarray", (v,))?,))?;
    let count = masked.len()?;
    if count == 0 {
        return Ok(());
    }
    let first: Vec<usize> = masked.get_item(0)?.extract()?;
    let at = first.first().map_or(String::new(), |i| format!(", the first at {unit} {i}"));
    Err(OdocalError::new_err(format!(
        "{name}: a masked array with {count} masked value(s){at}; numpy would hand over the values under the mask \
         as data: drop those samples (a new part where samples are missing), or give the array without a mask"
    )))
}

/// A table argument `name`: anything numpy makes a 2-D float64 array of,
/// with `rows` rows (one per time). Anything else raises `OdocalError` as
/// [`column`] does.
pub(crate) fn table(name: &str, v: &Bound<'_, PyAny>, rows: usize) -> PyResult<numpy::ndarray::Array2<f64>> {
    refuse_masked(name, v, "row")?;
    match v.extract::<numpy::PyArrayLike2<'_, f64, numpy::AllowTypeChange>>() {
        Ok(a) => Ok(a.as_array().to_owned()),
        Err(e) => Err(not_an_array_of(
            name,
            v,
            2,
            &format!("a 2-D array of {rows} rows (one per time in t) × the stream's columns"),
            &e,
        )),
    }
}

/// The Python type name of `v`, for messages (`value` when it cannot be
/// read).
pub(crate) fn type_name(v: &Bound<'_, PyAny>) -> String {
    v.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "value".into())
}

/// The error of an argument `name` that numpy could not make an array of
/// `ndim` dimensions of (its error `e`): what it got (type and numpy's
/// shape) and what is `expected`; numpy's message when the shape fits
/// (values that are not numbers).
pub(crate) fn not_an_array_of(name: &str, v: &Bound<'_, PyAny>, ndim: usize, expected: &str, e: &PyErr) -> PyErr {
    let kind = type_name(v);
    let shape =
        v.py().import("numpy").and_then(|np| np.call_method1("shape", (v,))).and_then(|s| s.extract::<Vec<usize>>());
    crate::OdocalError::new_err(match shape {
        Ok(s) if s.len() != ndim => {
            format!("{name}: got a {kind} of shape {}, where {expected} is expected", shape_text(&s))
        }
        _ => {
            let why = e.value(v.py()).str().map(|m| m.to_string()).unwrap_or_else(|_| e.to_string());
            format!("{name}: {why}; {expected} is expected")
        }
    })
}

/// A shape as numpy prints it: `()`, `(5,)`, `(10, 2)`.
pub(crate) fn shape_text(s: &[usize]) -> String {
    match s {
        [n] => format!("({n},)"),
        s => format!("({})", s.iter().map(usize::to_string).collect::<Vec<_>>().join(", ")),
    }
}
