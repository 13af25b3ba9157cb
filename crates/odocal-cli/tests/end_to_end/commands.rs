//! The commands other than `calibrate` and `follow`: their option errors
//! are usage errors naming the flag, their hints name options they have,
//! and `experiment` writes its files as one.

use std::path::Path;
use std::process::Command;

use crate::common::{odocal, simulated_drive, stderr};

/// Asserts that `args` is refused with exit code `code` and a message
/// holding every one of `needles`; returns the message.
fn refused_with(code: i32, args: &[&str], needles: &[&str]) -> String {
    let o = odocal(args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(code), "{args:?}: {e}");
    for n in needles {
        assert!(e.contains(n), "{args:?}: '{n}' not in: {e}");
    }
    e
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf8")
}

#[test]
fn experiment_counts_and_length_are_usage_errors_naming_the_flag() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("exp");
    let out = s(&out);
    refused_with(
        2,
        &["experiment", "--out", out, "--batches", "1000000"],
        &["--batches", "above its ceiling of 100000"],
    );
    refused_with(2, &["experiment", "--out", out, "--batches", "0"], &["--batches", "must be at least 1"]);
    refused_with(2, &["experiment", "--out", out, "--length-km", "3000"], &["--length-km", "limit of 2000 km"]);
    assert!(!dir.path().join("exp").exists(), "a refused experiment made its folder");
}

#[test]
fn bad_command_lines_exit_with_the_usage_code() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("s.csv");
    let e = refused_with(2, &["simulate", "--out", s(&out), "--ce-ramp-per-hour", "nan"], &["--ce-ramp-per-hour"]);
    assert!(!e.contains("drift.c_e_relative_per_hour"), "an internal key named: {e}");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    refused_with(
        2,
        &["validate", &d, "--theta", "2,0,1.6,0", "--params-node", "foo"],
        &["--params-node", "θ was given as numbers"],
    );
    refused_with(
        2,
        &["calibrate", &d, "--method", "batch-gn", "--json", "-", "--report", "-"],
        &["--json and --report both go to stdout"],
    );
}

#[test]
fn count_ceilings_of_validate_and_compensate_are_named() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let c = dir.path().join("c.csv");
    refused_with(
        2,
        &["validate", &d, "--theta", "2,0,1.6,0", "--validation-length", "20000000"],
        &["--validation-length = 20000000 is above its ceiling of 10000000"],
    );
    refused_with(
        2,
        &["compensate", &d, "--theta", "2,0,1.6,0", "--segment-length", "100000001", "--out", s(&c)],
        &["--segment-length = 100000001 is above its ceiling of 10000000"],
    );
    let help = crate::common::stdout(&odocal(&["validate", "--help"]));
    let line = help.lines().skip_while(|l| !l.contains("--validation-length")).nth(1).unwrap_or_default();
    assert!(line.contains("[default: 1300]"), "{help}");
}

#[test]
fn experiment_hints_name_only_its_own_options() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("exp");
    let e = refused_with(1, &["experiment", "--out", s(&out), "--length-km", "0.2"], &["too short", "--length-km"]);
    assert!(!e.contains("--validation-length"), "{e}");
    let csv = dir.path().join("rav4.csv");
    let m = format!("{}/../odocal/tests/data/comma2k19-rav4/manifest.toml", env!("CARGO_MANIFEST_DIR"));
    let o = odocal(&["import", &m, "--out", s(&csv)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e = refused_with(
        1,
        &["experiment", "--out", s(&out), "--drive", s(&csv)],
        &["not observable", "odocal calibrate DRIVE --fix c_d,t_r,d --min-yaw-rate 0"],
    );
    assert!(!e.contains("(--fix"), "{e}");
}

#[test]
fn messages_name_the_option_and_the_problem() {
    let dir = tempfile::tempdir().expect("tmp");
    let x = dir.path().join("x.csv");
    refused_with(1, &["import", "-", "--out", s(&x)], &["-: a manifest is read from a file, not from stdin"]);
    refused_with(
        2,
        &["simulate", "--out", s(&x), "--noise", "random:18446744073709551616"],
        &["above the largest, 18446744073709551615"],
    );
    refused_with(2, &["simulate", "--out", s(&x), "--noise", "random: 5"], &["without spaces"]);
    std::fs::write(dir.path().join("afile"), "").expect("write");
    let out = dir.path().join("afile/exp");
    refused_with(
        1,
        &["experiment", "--out", s(&out), "--length-km", "0.5", "--batches", "2"],
        &["--out", "cannot create"],
    );
}

/// The experiment's files by name and content.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .expect("read dir")
        .map(|e| {
            let e = e.expect("entry");
            (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).expect("read"))
        })
        .collect();
    v.sort();
    v
}

#[cfg(target_os = "linux")]
#[test]
fn experiment_force_that_fails_to_write_leaves_the_old_experiment() {
    let dir = tempfile::tempdir().expect("tmp");
    let exp = dir.path().join("exp");
    let o = odocal(&["experiment", "--out", s(&exp), "--length-km", "3", "--batches", "5"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let before = files(&exp);
    // Files larger than 140 blocks of 512 bytes cannot be written (Fig. 6 is).
    let bin = env!("CARGO_BIN_EXE_odocal");
    let script = format!(
        "trap '' XFSZ; ulimit -f 140; exec '{bin}' -q experiment --out '{}' --length-km 3 --seed 7 --force \
         --batches 5",
        s(&exp)
    );
    let o = Command::new("sh").args(["-c", &script]).output().expect("run sh");
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("File too large"), "{}", stderr(&o));
    assert_eq!(files(&exp), before, "a failed write changed the experiment's files");
}

#[test]
fn demo_help_names_the_calibrate_options_it_lacks() {
    let help = crate::common::stdout(&odocal(&["demo", "--help-all"]));
    assert!(help.contains("except --db and --vehicle"), "{help}");
    let o = odocal(&["demo", "--db", "h.db"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}

/// A parameter file of a simulated car's θ whose calibration estimated a
/// heading offset of `delta` rad.
fn param_file(dir: &Path, name: &str, delta: f64) -> String {
    let p = dir.join(name);
    let text = format!(
        "odocal:\n  ros__parameters:\n    c_e: 1.948\n    c_d: -0.0018\n    t_r: 1.53\n    d: 0.0007\n    \
         lever_x: 0.0\n    lever_x_held: true\n    lever_y: 0.0\n    lever_y_held: true\n    \
         heading_offset: {delta}\n    heading_offset_sigma: 0.001\n"
    );
    std::fs::write(&p, text).expect("write");
    s(&p).to_owned()
}

#[test]
fn an_implausible_re_estimated_heading_offset_is_warned_about() {
    let dir = tempfile::tempdir().expect("tmp");
    let van = format!("{}/../odocal/tests/data/psu-mapping-van/manifest.toml", env!("CARGO_MANIFEST_DIR"));
    let sim_car = param_file(dir.path(), "car.yaml", 0.0);
    let c = dir.path().join("c.csv");
    // The simulated car's θ on the van: the offset soaks up ~250 mrad.
    let o = odocal(&["compensate", &van, "--theta", &sim_car, "--out", s(&c)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("beyond the plausible ±100 mrad"), "{}", stderr(&o));
    assert!(stderr(&o).contains("another vehicle's"), "{}", stderr(&o));
    // On a simulated drive the re-estimate is a few mrad: no warning …
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "5", "--seed", "9"]);
    let o = odocal(&["validate", &d, "--theta", &sim_car]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("warning: the heading offset"), "{}", stderr(&o));
    // … unless the file's offset is many cluster-robust σ away.
    let far = param_file(dir.path(), "far.yaml", 0.12);
    let o = odocal(&["validate", &d, "--theta", &far]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("times its cluster-robust σ"), "{}", stderr(&o));
}

#[test]
fn a_drift_that_changes_nothing_is_no_drift() {
    let dir = tempfile::tempdir().expect("tmp");
    let plain = simulated_drive(dir.path(), "plain.csv", &["--length-km", "1"]);
    let zero =
        simulated_drive(dir.path(), "zero.csv", &["--length-km", "1", "--cd-step", "0@0", "--ce-ramp-per-hour", "0"]);
    let read = |p: &str| std::fs::read(p).expect("read");
    assert_eq!(read(&plain), read(&zero), "the drive differs");
    let sidecar = std::fs::read_to_string(dir.path().join("zero.json")).expect("sidecar");
    assert!(!sidecar.contains("\"drift\"") && !sidecar.contains("theta_true_end"), "{sidecar}");
}
