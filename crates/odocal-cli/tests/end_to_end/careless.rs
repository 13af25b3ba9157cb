//! Careless command lines end before any work with an error that names the
//! option and says what to give instead: usage errors (exit 2) for a value
//! the option cannot take, exit 1 for an output that cannot be written
//! where it is asked for.

use std::path::Path;

use crate::common::{assert_fails, odocal, s, simulated_drive, stderr};

#[test]
fn threads_outside_1_to_the_ceiling_are_usage_errors() {
    let v = ["validate", "drive.csv", "--theta", "2,0,1.6,0"];
    let with = |n: &'static str| [&["--threads", n][..], &v[..]].concat();
    assert_fails(&with("0"), 2, &["--threads", "must be at least 1"]);
    assert_fails(&with("5000"), 2, &["--threads", "above the ceiling of 1024"]);
}

/// A `--params-out` whose name gives no format is refused before the
/// calibration runs, and before `follow` records anything in the history.
#[test]
fn a_params_out_without_a_format_is_refused_before_any_work() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let txt = dir.path().join("odometry.txt");
    assert_fails(&["calibrate", &d, "--params-out", s(&txt)], 2, &["--params-out", ".yaml", ".json"]);
    let db = dir.path().join("h.sqlite");
    assert_fails(&["follow", &d, "--vehicle", "v", "--db", s(&db), "--params-out", s(&txt)], 2, &["--params-out"]);
    assert!(!db.exists(), "the history was opened before the command line was checked");
    assert!(!txt.exists());
}

/// An output in a folder that does not exist, or onto a directory, is
/// named before the work (whose result would be lost), without the name of
/// a temporary file.
#[test]
fn an_output_that_cannot_be_written_is_named_before_any_work() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let missing = dir.path().join("no-such-folder").join("r.json");
    let e = assert_fails(&["calibrate", &d, "--json", s(&missing)], 1, &["--json", "no-such-folder does not exist"]);
    assert!(!e.contains(".r.json."), "the temporary file named: {e}");
    assert_fails(&["calibrate", &d, "--report", s(dir.path())], 1, &["--report", "is a directory"]);
    let under_file = Path::new(&d).join("r.yaml");
    assert_fails(&["calibrate", &d, "--params-out", s(&under_file)], 1, &["d.csv is not a folder"]);
    let csv = dir.path().join("nowhere").join("x.csv");
    assert_fails(&["simulate", "--length-km", "1", "--out", s(&csv)], 1, &["--out", "does not exist"]);
    // experiment creates its folder.
    let out = dir.path().join("new").join("exp");
    let o = odocal(&["experiment", "--length-km", "0.5", "--batches", "2", "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("report.md").exists());
}

#[test]
fn simulator_flags_are_checked_as_flags() {
    let out = std::env::temp_dir().join("odocal-never-written.csv");
    let o = s(&out);
    assert_fails(&["simulate", "--length-km", "0", "--out", o], 2, &["--length-km", "positive"]);
    assert_fails(&["simulate", "--noise", "loud", "--out", o], 2, &["--noise", "unknown noise preset 'loud'"]);
    assert_fails(&["demo", "--noise", "loud"], 2, &["--noise"]);
    assert_fails(&["simulate", "--substeps", "0", "--out", o], 2, &["--substeps", "1..=10000"]);
    assert_fails(&["experiment", "--length-km", "nan", "--out", o], 2, &["--length-km"]);
    assert!(!out.exists());
}

/// `-` for a drive (stdin) is refused with what to do, not "-: No such
/// file or directory".
#[test]
fn a_drive_from_stdin_is_refused_saying_why() {
    assert_fails(&["validate", "-", "--theta", "2,0,1.6,0"], 1, &["-: a drive is read from a file, not from stdin"]);
    assert_fails(&["calibrate", "-"], 1, &["save it first"]);
}

/// Flags the calibration settings refuse are usage errors naming the flag,
/// not the library's field (`free`, `initial_batches`).
#[test]
fn refused_calibration_flags_are_usage_errors_naming_the_flag() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let e = assert_fails(&["calibrate", &d, "--fix", "c_e,c_d,t_r,d"], 2, &["--fix holds every parameter of θ"]);
    assert!(e.contains("odocal validate --theta") && !e.contains("`free`"), "{e}");
    let e = assert_fails(&["calibrate", &d, "--method", "three-step", "--batches", "0"], 2, &["--batches = 0"]);
    assert!(!e.contains("initial_batches"), "{e}");
    assert_fails(&["calibrate", &d, "--method", "three-step", "--picks", "0"], 2, &["--picks = 0"]);
    assert_fails(&["calibrate", &d, "--method", "batch-gn", "--eiv-window", "600"], 2, &["--eiv-window applies to"]);
}

/// `follow`'s online-calibrator flags out of range are usage errors naming
/// the flag, the value given and the range, before the history is opened
/// (the library's check names its field, `information_scale`, which is no
/// flag), and before a drive is looked for.
#[test]
fn follow_flags_out_of_range_name_the_flag() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let db = dir.path().join("h.sqlite");
    let cases: [(&str, &str, &str); 17] = [
        ("--information-scale", "0", "--information-scale = 0: must be within 1e-6 … 1"),
        ("--information-scale", "1e308", "--information-scale = 1e308: must be within 1e-6 … 1"),
        ("--sigma-factors", "1,0,1,1", "--sigma-factors = 1,0,1,1: must be positive"),
        ("--random-walk", "nan,0,0,0", "--random-walk = NaN,0,0,0: c_e's sd after one hour NaN is outside 0 … 0.1"),
        ("--random-walk", "1e308,1,1,1", "c_e's sd after one hour 1e308 is outside 0 … 0.1 (a fraction of c_e)"),
        ("--random-walk", "0,0,2,0", "--random-walk = 0,0,2,0: t_r's sd after one hour 2 is outside 0 … 1 (m)"),
        ("--prior-sd", "0.02,0,0.05,2e-3", "--prior-sd = 0.02,0,0.05,0.002: c_d's prior sd 0 is outside 1e-6 … 0.05"),
        ("--prior-sd", "1e308,5e-3,0.05,2e-3", "c_e's prior sd 1e308 is outside 1e-6 … 0.5 (a fraction of c_e)"),
        ("--prior-sd", "0.02,5e-3,0.05,1", "--prior-sd = 0.02,0.005,0.05,1: d's prior sd 1 is outside 1e-6 … 0.05"),
        ("--heading-offset-prior-sd", "0", "--heading-offset-prior-sd = 0: must be positive"),
        ("--informative-yaw-rate", "nan", "--informative-yaw-rate = NaN: must be a non-negative number"),
        ("--iterations-per-segment", "0", "--iterations-per-segment = 0: must be at least 1"),
        ("--steady-window-s", "0", "--steady-window-s = 0: must be positive"),
        ("--recent-validation-segments", "0", "--recent-validation-segments = 0: must be at least 1"),
        ("--recent-validation-segments", "99999999999", "= 99999999999: must be at least 1 and at most 10000"),
        ("--steady-s", "-1", "--steady-s must be a non-negative number of seconds"),
        ("--max-sigma", "1,1,0,1", "--max-sigma must be four positive numbers"),
    ];
    for (flag, value, needle) in cases {
        let given = format!("{flag}={value}");
        let e = assert_fails(&["follow", &d, "--vehicle", "v", "--db", s(&db), &given], 2, &[needle]);
        assert!(!e.contains("invalid option"), "{e}");
        assert!(!db.exists(), "{flag}: the history was opened before the flags were checked");
        assert_fails(&["follow", "no-such.csv", "--vehicle", "v", "--db", s(&db), &given], 2, &[needle]);
    }
}
