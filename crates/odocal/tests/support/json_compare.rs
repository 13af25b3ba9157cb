//! Comparison of a JSON value with a golden one, shared by the library's and
//! the CLI's golden tests (`#[path]`-included by both).

use std::path::Path;

use serde_json::Value;

/// Relative tolerance of the comparison. The code paths keep their
/// floating-point order, so the numbers are expected to be bitwise equal
/// (`ODOCAL_GOLDEN_EXACT=1` checks that); 1e-12 leaves room only for a
/// compiler or libm reordering a sum on another machine.
pub const REL_TOL: f64 = 1e-12;

/// [`REL_TOL`], or 0 (bitwise equality) with `ODOCAL_GOLDEN_EXACT=1`.
pub fn tolerance() -> f64 {
    if std::env::var_os("ODOCAL_GOLDEN_EXACT").is_some() {
        0.0
    } else {
        REL_TOL
    }
}

/// `x` and `y` agree to [`tolerance`] relative (NaN never agrees).
pub fn close(x: f64, y: f64) -> bool {
    (x - y).abs() <= tolerance() * x.abs().max(y.abs())
}

/// Every difference between `want` and `got` (numbers to [`tolerance`]), as
/// JSON-pointer-like paths. Keys of `got` that `want` lacks are ignored.
pub fn compare(want: &Value, got: &Value, path: &str, out: &mut Vec<String>) {
    match (want, got) {
        (Value::Object(a), Value::Object(b)) => {
            for (k, av) in a {
                match b.get(k) {
                    Some(bv) => compare(av, bv, &format!("{path}/{k}"), out),
                    None => out.push(format!("{path}/{k}: missing")),
                }
            }
        }
        (Value::Array(a), Value::Array(b)) => {
            if a.len() != b.len() {
                out.push(format!("{path}: length {} vs {}", a.len(), b.len()));
            }
            for (i, (av, bv)) in a.iter().zip(b).enumerate() {
                compare(av, bv, &format!("{path}/{i}"), out);
            }
        }
        (Value::Number(a), Value::Number(b)) => {
            let (x, y) = (a.as_f64().unwrap_or(f64::NAN), b.as_f64().unwrap_or(f64::NAN));
            if !close(x, y) {
                out.push(format!("{path}: {x:e} vs {y:e}"));
            }
        }
        _ => {
            if want != got {
                out.push(format!("{path}: {want} vs {got}"));
            }
        }
    }
}

/// With `ODOCAL_BLESS` set, writes `got` to `path` (the golden file) and
/// returns `None`; otherwise asserts that `got` matches the golden file and
/// returns it.
pub fn check_or_bless(path: &Path, got: &Value) -> Option<Value> {
    if std::env::var_os("ODOCAL_BLESS").is_some() {
        std::fs::create_dir_all(path.parent().expect("dir")).expect("mkdir");
        std::fs::write(path, serde_json::to_string_pretty(got).expect("json") + "\n").expect("write golden");
        return None;
    }
    let want: Value = serde_json::from_str(&std::fs::read_to_string(path).expect("golden file")).expect("json");
    let mut diffs = Vec::new();
    compare(&want, got, "", &mut diffs);
    assert!(diffs.is_empty(), "{} differences from {}:\n{}", diffs.len(), path.display(), diffs.join("\n"));
    Some(want)
}
