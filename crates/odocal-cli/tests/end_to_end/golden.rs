//! Golden JSON of the `odocal` binary on a fixed simulated drive.
//!
//! `odocal simulate --seed 7 --length-km 4` writes the drive; `calibrate`
//! (batch-gn, three-step with small step-1 settings, batch-gn with a
//! hold-out) and `validate` (with the reachable minimum) run on it with
//! `--json -`. The contract's fields (docs/reference.md, "Outputs"), the covariance, every step-1 batch score
//! and the truth block are compared with `tests/data/golden/cli.json`,
//! written by the binary of main at commit 8f30b25. To write it again (only for an intended change of
//! the numbers): `ODOCAL_BLESS=1 cargo test -p odocal-cli --test end_to_end golden::`.

use crate::common;
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::{json, Value};

#[path = "../../../odocal/tests/support/json_compare.rs"]
mod json_compare;
use json_compare::check_or_bless;

fn golden_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/golden/cli.json")
}

/// Runs odocal and parses the JSON it prints on stdout.
fn run_json(args: &[&str]) -> Value {
    let o = Command::new(env!("CARGO_BIN_EXE_odocal")).args(args).arg("--quiet").output().expect("run odocal");
    assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{args:?}: stdout is not JSON: {e}"))
}

/// Copies the fields at `pointers` (e.g. "/theta") into a new object.
fn pick(v: &Value, pointers: &[&str]) -> Value {
    let mut out = json!({});
    for p in pointers {
        let x = v.pointer(p).unwrap_or_else(|| panic!("report lacks {p}: {v}"));
        out[p.trim_start_matches('/').replace('/', ".")] = x.clone();
    }
    out
}

/// The contract's fields (docs/reference.md, "Outputs") of a calibrate report and the numbers behind them.
fn pin_calibrate(v: &Value) -> Value {
    assert!(v.pointer("/timing_s/total").and_then(Value::as_f64).is_some(), "timing_s.total");
    let mut p = pick(
        v,
        &[
            "/method",
            "/theta",
            "/validation/mean_position_error_m",
            "/validation/segments",
            "/validation/held_out",
            "/initial/theta",
            "/initial/mean_position_error_m",
            "/identification/covariance",
            "/identification/final_cost",
            "/identification/iterations",
            "/segments",
            "/truth",
        ],
    );
    if let Some(b) = v.pointer("/initial_step/batches").and_then(Value::as_array) {
        p["initial_step.batches"] = b
            .iter()
            .map(|b| pick(b, &["/segment_starts", "/score/theta", "/score/mean_position_error_m", "/iterations"]))
            .collect();
        p["initial_step.picked_batches"] = v["initial_step"]["picked_batches"].clone();
    }
    if let Some(c) = v.pointer("/compensation") {
        if !c.is_null() {
            p["compensation"] =
                pick(c, &["/segments", "/jobs", "/failed_jobs", "/qp_solves", "/rms_relative_input_change"]);
        }
    }
    p
}

fn theta_arg(v: &Value) -> String {
    format!("{},{},{},{}", v["c_e"], v["c_d"], v["t_r"], v["d"])
}

fn current(dir: &Path) -> Value {
    let drive = common::simulated_drive(dir, "drive.csv", &["--seed", "7", "--length-km", "4"]);
    let d = drive.as_str();
    let gn = run_json(&["calibrate", d, "--method", "batch-gn", "--json", "-"]);
    let ts =
        run_json(&["calibrate", d, "--method", "three-step", "--batches", "6", "--final-segments", "8", "--json", "-"]);
    let held = run_json(&["calibrate", d, "--method", "batch-gn", "--holdout", "first-half", "--json", "-"]);
    let th = theta_arg(&ts["theta"]);
    // δ held as given (0), as the file was written: `validate` re-estimates
    // the drive's own by default.
    let val = run_json(&[
        "validate",
        d,
        "--theta",
        &th,
        "--carry-heading-offset",
        "--reachable-minimum",
        "--seed",
        "3",
        "--json",
        "-",
    ]);
    for (name, v) in [("batch-gn", &gn), ("three-step", &ts), ("hold-out", &held), ("validate", &val)] {
        assert_eq!(v["schema_version"], 1, "{name} report: schema_version");
    }
    json!({
        "calibrate_batch_gn": pin_calibrate(&gn),
        "calibrate_three_step": pin_calibrate(&ts),
        "calibrate_batch_gn_holdout_first_half": pin_calibrate(&held),
        "validate": pick(&val, &[
            "/theta",
            "/mean_position_error_m",
            "/segments",
            "/per_segment_m",
            "/reachable_minimum/theta",
            "/reachable_minimum/mean_position_error_m",
        ]),
    })
}

#[test]
fn cli_json_matches_the_golden_file() {
    let dir = tempfile::tempdir().expect("tmp");
    let got = current(dir.path());
    check_or_bless(&golden_path(), &got);
}
