//! End-to-end tests of the `odocal` binary: contract (docs/reference.md), bad input,
//! determinism.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::{odocal, simulated_drive, stderr, stdout};

/// Asserts a failed run with exit code 1 and one error line containing all `needles`.
fn assert_error(o: &Output, needles: &[&str]) {
    assert_error_code(o, 1, needles);
}

/// A flag the settings refuse (of another method, say): a usage error.
fn assert_usage_error(o: &Output, needles: &[&str]) {
    assert_error_code(o, 2, needles);
}

fn assert_error_code(o: &Output, code: i32, needles: &[&str]) {
    assert_eq!(o.status.code(), Some(code), "stderr: {}", stderr(o));
    let e = stderr(o);
    assert!(e.starts_with("error: "), "{e}");
    assert_eq!(e.trim_end().lines().count(), 1, "one line: {e}");
    for n in needles {
        assert!(e.contains(n), "expected '{n}' in: {e}");
    }
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).expect("write fixture");
    p
}

fn good_rows(n: usize) -> String {
    let mut s = String::from("t,px,py,psi,n_rl,n_rr,beta,a_y\n");
    for i in 0..n {
        s.push_str(&format!("{},{},0,0,5,5,0,0\n", i as f64 * 0.025, i as f64 * 0.25));
    }
    s
}

#[test]
fn missing_column_lists_columns_found() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", "t,px,py,psi,n_rl,beta\n0,0,0,0,1,0\n");
    let o = odocal(&["calibrate", p.to_str().expect("utf8")]);
    assert_error(&o, &["d.csv", "missing column(s) n_rr, a_y", "columns found: t, px, py, psi, n_rl, beta"]);
}

#[test]
fn nan_names_line_and_column() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(10).replacen("0.05,0.5,", "0.05,nan,", 1));
    let o = odocal(&["calibrate", p.to_str().expect("utf8")]);
    assert_error(&o, &["d.csv: line 4, column 'px'", "not finite"]);
}

#[test]
fn text_value_names_line_and_column() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(10).replacen("0.05,0.5,0,0,5", "0.05,0.5,0,0,five", 1));
    let o = odocal(&["validate", p.to_str().expect("utf8"), "--theta", "2,0,1.6,0"]);
    assert_error(&o, &["line 4, column 'n_rl'", "'five' is not a number"]);
}

#[test]
fn non_monotonic_time_names_line() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(10).replacen("\n0.1,", "\n0.05,", 1));
    let o = odocal(&["calibrate", p.to_str().expect("utf8")]);
    assert_error(&o, &["line 6, column 't'", "not strictly increasing"]);
}

#[test]
fn non_uniform_time_names_line() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(10).replacen("0.1,", "0.11,", 1));
    let o = odocal(&["calibrate", p.to_str().expect("utf8")]);
    assert_error(&o, &["line 6, column 't'", "uniform"]);
}

#[test]
fn too_few_samples() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(100));
    let o = odocal(&["calibrate", p.to_str().expect("utf8")]);
    assert_error(&o, &["100 samples", "a calibration segment needs 651"]);
    let o = odocal(&["validate", p.to_str().expect("utf8"), "--theta", "2,0,1.6,0"]);
    assert_error(&o, &["100 samples", "too short for one validation segment", "a part needs at least 1351 samples"]);
    let o = odocal(&["validate", p.to_str().expect("utf8"), "--theta", "2,0,1.6,0", "--validation-length", "40"]);
    assert!(o.status.success(), "{}", stderr(&o));
}

#[test]
fn empty_and_header_only_files() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "e.csv", "");
    assert_error(&odocal(&["calibrate", p.to_str().expect("utf8")]), &["e.csv", "the file is empty"]);
    let p = write(d.path(), "h.csv", "t,px,py,psi,n_rl,n_rr,beta,a_y\n");
    assert_error(&odocal(&["calibrate", p.to_str().expect("utf8")]), &["h.csv", "no data rows"]);
}

#[test]
fn unreadable_file() {
    let o = odocal(&["calibrate", "/nonexistent/drive.csv"]);
    assert_error(&o, &["/nonexistent/drive.csv", "No such file"]);
}

#[test]
fn bad_theta_argument() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(10));
    let o = odocal(&["validate", p.to_str().expect("utf8"), "--theta", "2,0,-1,0"]);
    assert_eq!(o.status.code(), Some(2), "clap usage error: {}", stderr(&o));
    assert!(stderr(&o).contains("t_r = -1 m must be positive"), "{}", stderr(&o));
}

/// θ's text names each parameter itself, so a line that embeds it does not
/// label it again (`at θ = c_e = …`).
#[test]
fn validate_prints_the_reachable_minimums_theta_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = simulated_drive(dir.path(), "d.csv", &["--seed", "2", "--length-km", "2"]);
    let o = odocal(&["validate", &d, "--theta", "1.95,-0.002,1.53,0.0008", "--reachable-minimum", "--seed", "3"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = stdout(&o);
    let line = text.lines().find(|l| l.starts_with("reachable minimum: ")).expect("the reachable minimum");
    assert!(line.contains(" m at c_e = ") && line.contains(", d = "), "{line}");
    assert!(!line.contains("θ ="), "{line}");
    assert!(text.lines().any(|l| l.starts_with("θ: c_e = 1.950000 m")), "{text}");
}

#[test]
fn straight_drive_reports_unobservable_parameters() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(3000));
    let o = odocal(&["calibrate", p.to_str().expect("utf8"), "--method", "batch-gn"]);
    assert_error(&o, &["c_d, t_r, d not observable", "none of the", "--fix"]);
}

/// The command the error above gives works on a perfectly straight drive:
/// `--min-yaw-rate 0` selects every segment (each with a peak yaw rate of
/// 0), and c_e alone is calibrated.
#[test]
fn min_yaw_rate_zero_calibrates_c_e_on_a_straight_drive() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(3000));
    let args = ["calibrate", p.to_str().expect("utf8"), "--method", "batch-gn", "--fix", "c_d,t_r,d"];
    let o = odocal(&[&args[..], &["--min-yaw-rate", "0", "--json", "-"]].concat());
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("json");
    let (cut, selected) = (&v["segments"]["cut"], &v["segments"]["selected"]);
    assert!(cut.as_u64().is_some_and(|n| n > 0) && selected == cut, "{}", v["segments"]);
    // 0.25 m per sample on 5 rev/s at 40 Hz: 2 m per revolution.
    let c_e = v["theta"]["c_e"].as_f64().expect("c_e");
    assert!((c_e - 2.0).abs() < 1e-6, "c_e = {c_e}");
}

/// A negative number given to a numeric option is taken as its value, so
/// the option's own range message names it (a usage error), not clap's
/// advice to pass it after `--`; on every subcommand that has such options.
#[test]
fn a_negative_number_gets_the_options_own_range_message() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(100));
    let (p, db) = (p.to_str().expect("utf8"), d.path().join("h.sqlite"));
    let out = d.path().join("s.csv");
    let (db, out) = (db.to_str().expect("utf8"), out.to_str().expect("utf8"));
    let follow = ["follow", p, "--vehicle", "van", "--db", db];
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["calibrate", p, "--min-yaw-rate", "-1"], "'-1' is not a non-negative number of rad/s"),
        (
            vec!["calibrate", p, "--segment-length", "-5"],
            "--segment-length <SEGMENT_LENGTH>': must be at least 2 samples, got -5",
        ),
        (vec!["calibrate", p, "--batches", "-3"], "--batches <BATCHES>': must be 0 or more, got -3"),
        (vec!["calibrate", p, "--correct-bias", "-2"], "B must be an even number of at least 2, got -2"),
        (
            vec!["calibrate", p, "--threads", "-2"],
            "must be at least 1 (leave --threads out for one thread per core), got -2",
        ),
        (vec!["demo", "--sim-seed", "-1"], "--sim-seed <SIM_SEED>': must be 0 or more, got -1"),
        (
            vec!["validate", p, "--theta", "2,0,1.6,0", "--validation-length", "-1"],
            "must be at least 2 samples, got -1",
        ),
        (vec!["compensate", p, "--theta", "2,0,1.6,0", "--out", out, "--segment-length", "-650"], "got -650"),
        (vec!["simulate", "--out", out, "--seed", "-1"], "--seed <SEED>': must be 0 or more, got -1"),
        (vec!["simulate", "--out", out, "--substeps", "-4"], "-4 is not in 1..=10000"),
        ([&follow[..], &["--steady-s", "-1"]].concat(), "--steady-s must be a non-negative number of seconds, got -1"),
        ([&follow[..], &["--min-yaw-rate", "-0.5"]].concat(), "'-0.5' is not a non-negative number of rad/s"),
        ([&follow[..], &["--information-scale", "-1"]].concat(), "--information-scale = -1"),
        ([&follow[..], &["--iterations-per-segment", "-1"]].concat(), "must be 0 or more, got -1"),
        ([&follow[..], &["--max-sigma", "-1,1,1,1"]].concat(), "--max-sigma must be four positive numbers"),
        ([&follow[..], &["--random-walk", "-1,0,0,0"]].concat(), "--random-walk = -1,0,0,0"),
    ];
    for (args, message) in cases {
        let o = odocal(&args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {e}");
        assert!(!e.contains("to pass '-"), "{args:?}: {e}");
        assert!(e.contains(message), "{args:?}: expected '{message}' in: {e}");
    }
    assert!(!std::path::Path::new(db).exists() && !std::path::Path::new(out).exists(), "nothing written");
}

#[test]
fn simulate_calibrate_validate_contract_and_determinism() {
    let d = tempfile::tempdir().expect("tmp");
    let drive = d.path().join("drive.csv");
    let dstr = drive.to_str().expect("utf8");
    let o = odocal(&["simulate", "--seed", "3", "--length-km", "3", "--out", dstr]);
    assert!(o.status.success(), "{}", stderr(&o));
    let first = std::fs::read(&drive).expect("csv");
    let side: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.path().join("drive.json")).expect("sidecar")).expect("json");
    for k in ["c_e", "c_d", "t_r", "d"] {
        assert!(side["theta_true"][k].is_f64(), "sidecar theta_true.{k}");
    }
    // Same seed: byte-identical.
    let again = d.path().join("again.csv");
    let o = odocal(&["simulate", "--seed", "3", "--length-km", "3", "--out", again.to_str().expect("utf8")]);
    assert!(o.status.success());
    assert!(first == std::fs::read(&again).expect("csv"), "same seed must give identical bytes");

    let report = d.path().join("r.json");
    let o = odocal(&["calibrate", dstr, "--method", "batch-gn", "--json", report.to_str().expect("utf8")]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("calibrated"), "{}", stdout(&o));
    let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&report).expect("r")).expect("json");
    assert_eq!(r["method"], "batch-gn");
    for k in ["c_e", "c_d", "t_r", "d"] {
        assert!(r["theta"][k].is_f64() && r["initial"]["theta"][k].is_f64());
    }
    assert!(r["validation"]["mean_position_error_m"].is_f64());
    assert!(r["validation"]["segments"].as_u64().expect("count") > 0);
    assert!(r["initial"]["mean_position_error_m"].is_f64());
    assert!(r["timing_s"]["total"].is_f64());
    // It improves on θ_0 and lands near the truth.
    assert!(r["validation"]["mean_position_error_m"].as_f64() < r["initial"]["mean_position_error_m"].as_f64());
    let c_e = r["theta"]["c_e"].as_f64().expect("c_e");
    assert!((c_e - side["theta_true"]["c_e"].as_f64().expect("true")).abs() < 0.01, "c_e {c_e}");

    // Same input, same result.
    let o2 = odocal(&["calibrate", dstr, "--method", "batch-gn", "--json", "-"]);
    assert!(o2.status.success());
    let r2: serde_json::Value = serde_json::from_slice(&o2.stdout).expect("json on stdout");
    assert_eq!(r["theta"], r2["theta"]);
    assert_eq!(r["validation"], r2["validation"]);

    let th = format!("{},{},{},{}", r["theta"]["c_e"], r["theta"]["c_d"], r["theta"]["t_r"], r["theta"]["d"]);
    // With the heading offset held as the calibration held it (validate
    // re-estimates the drive's own by default).
    let o = odocal(&["validate", dstr, "--theta", &th, "--carry-heading-offset", "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert!(v["mean_position_error_m"].is_f64() && v["segments"].is_u64() && v["theta"]["c_e"].is_f64());
    let diff = (v["mean_position_error_m"].as_f64().expect("e")
        - r["validation"]["mean_position_error_m"].as_f64().expect("e"))
    .abs();
    assert!(diff < 1e-9, "validate agrees with calibrate's validation: {diff}");
}

#[test]
fn simulate_random_noise_world() {
    let d = tempfile::tempdir().expect("tmp");
    let drive = d.path().join("world.csv");
    let dstr = drive.to_str().expect("utf8");
    let o = odocal(&["simulate", "--seed", "2", "--length-km", "1", "--noise", "random:7", "--out", dstr]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("noise world random:7: "), "{}", stdout(&o));
    let side: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.path().join("world.json")).expect("sidecar")).expect("json");
    let world: ::odocal::sim::NoiseOptions = "random:7".parse().expect("world 7");
    let noise: ::odocal::sim::NoiseOptions = serde_json::from_value(side["settings"]["noise"].clone()).expect("noise");
    assert_eq!(noise, world);
    let o = odocal(&["simulate", "--length-km", "1", "--noise", "random:x", "--out", dstr]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("random:"), "{}", stderr(&o));
}

#[test]
fn demo_runs_and_compares_with_truth() {
    // The default method is eiv.
    let o = odocal(&["demo", "--length-km", "3", "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(r["method"], "eiv");
    assert_eq!(r["options"]["method"]["name"], "eiv");
    assert!(r["truth"]["theta"]["c_e"].is_f64() && r["eiv"]["noise"].is_object(), "{r}");
    let args = ["demo", "--length-km", "3", "--method", "three-step", "--batches", "4", "--final-segments", "6"];
    let o = odocal(&[&args[..], &["--json", "-"]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(r["method"], "three-step");
    assert!(r["truth"]["theta"]["c_e"].is_f64());
    assert_eq!(r["initial_step"]["batches"].as_array().map(Vec::len), Some(4));
    assert!(r["compensation"]["segments"].as_u64().expect("count") > 0);
    let o = odocal(&["demo", "--length-km", "3", "--method", "batch-gn"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    assert!(out.contains("simulated 3.0 km") && out.contains("error against truth"), "{out}");
}

/// A fixture manifest of the library crate's real-drive slices.
fn slice_manifest(name: &str) -> String {
    format!("{}/../odocal/tests/data/{name}/manifest.toml", env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn straight_real_drive_names_unobservable_parameters_and_the_command_to_run() {
    let m = slice_manifest("comma2k19-rav4");
    let o = odocal(&["calibrate", &m, "--method", "batch-gn"]);
    assert_eq!(o.status.code(), Some(1), "stderr: {}", stderr(&o));
    let e = stderr(&o);
    let last = e.trim_end().lines().last().expect("an error line");
    for n in ["error: ", "c_d, t_r, d not observable", "--fix c_d,t_r,d --min-yaw-rate 0", "--auto-fix"] {
        assert!(last.contains(n), "expected '{n}' in: {last}");
    }
}

/// EIV holds what the straight drive cannot determine at its start: the
/// table says "held" for them, as the JSON `sigma` says null, not a σ of 0.
#[test]
fn parameters_eiv_holds_print_held_not_a_zero_sigma() {
    let m = slice_manifest("comma2k19-rav4");
    let args = ["calibrate", &m, "--segment-length", "400", "--validation-length", "400"];
    let o = odocal(&args);
    let out = stdout(&o);
    let row = |name: &str| out.lines().find(|l| l.trim_start().starts_with(name)).unwrap_or_default().to_string();
    for p in ["t_r ", "d "] {
        let r = row(p);
        assert!(r.ends_with("held") && !r.contains("0.000000"), "{p}: {r}\n{out}");
    }
    assert!(!row("c_e ").contains("held"), "{out}");
    let o = odocal(&[&args[..], &["--json", "-"]].concat());
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("json");
    assert_eq!(v["sigma"]["t_r"], serde_json::Value::Null);
    assert!(v["sigma"]["c_e"].as_f64().is_some_and(|s| s > 0.0));
}

#[test]
fn auto_fix_calibrates_the_scale_of_a_straight_real_drive() {
    let m = slice_manifest("comma2k19-rav4");
    let args = ["calibrate", &m, "--method", "batch-gn", "--auto-fix", "--segment-length", "400"];
    let o = odocal(&[&args[..], &["--validation-length", "400", "--json", "-"]].concat());
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("json");
    assert_eq!(v["auto_fixed"], serde_json::json!(["c_d", "t_r", "d"]));
    // The slice's rear wheels integrate ~0.97 % short of the pose path
    // (the full 60 s: 0.90 %); nominal circumference 2.0 m.
    let c_e = v["theta"]["c_e"].as_f64().expect("c_e");
    assert!((2.0 * 1.005..2.0 * 1.015).contains(&c_e), "c_e = {c_e}");
    assert_eq!(v["theta"]["t_r"].as_f64(), Some(1.6), "t_r held at θ_0");
    assert!(v["wheel_scale"].as_str().expect("wheel_scale").contains("nominal circumference 2 m"));
    let o = odocal(&[&args[..], &["--validation-length", "400"]].concat());
    assert!(stdout(&o).contains("held at θ_0 (--auto-fix, not observable): c_d, t_r, d"), "{}", stdout(&o));
}

#[test]
fn calibrate_report_says_what_c_e_means_for_ticks() {
    let m = slice_manifest("psu-mapping-van");
    let args = ["calibrate", &m, "--method", "batch-gn", "--min-yaw-rate", "0", "--segment-length", "400"];
    let o = odocal(&[&args[..], &["--validation-length", "400"]].concat());
    assert!(o.status.success(), "stderr: {}", stderr(&o));
    let out = stdout(&o);
    assert!(out.contains("wheels: ticks, one model revolution = ticks_per_rev = 40360 ticks"), "{out}");
    // 130 s of highway: t_r and d are named (near-collinear with c_d).
    assert!(out.contains("NOT OBSERVABLE from these data (estimates not to be trusted): t_r, d"), "{out}");
}

#[test]
fn validate_on_another_drive() {
    let d = tempfile::tempdir().expect("tmp");
    let astr: &str = &simulated_drive(d.path(), "a.csv", &["--seed", "4", "--length-km", "3"]);
    let bstr: &str = &simulated_drive(d.path(), "b.csv", &["--seed", "5", "--length-km", "3"]);
    let o = odocal(&["calibrate", astr, "--method", "batch-gn", "--validate-on", bstr, "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(r["validation"]["held_out"], true);
    // The reported Ē_p is that of drive b: validate agrees (δ held as batch G-N held it).
    let th = format!("{},{},{},{}", r["theta"]["c_e"], r["theta"]["c_d"], r["theta"]["t_r"], r["theta"]["d"]);
    let v = odocal(&["validate", bstr, "--theta", &th, "--carry-heading-offset", "--json", "-"]);
    let v: serde_json::Value = serde_json::from_slice(&v.stdout).expect("json");
    let diff = (v["mean_position_error_m"].as_f64().expect("e")
        - r["validation"]["mean_position_error_m"].as_f64().expect("e"))
    .abs();
    assert!(diff < 1e-9, "{diff}");
    // Conflicts with --holdout; a missing file names the flag.
    let o = odocal(&["calibrate", astr, "--validate-on", bstr, "--holdout", "first-half"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let o = odocal(&["calibrate", astr, "--validate-on", "/nonexistent.csv"]);
    assert_error(&o, &["--validate-on /nonexistent.csv", "No such file"]);
}

/// Method eiv (the default) fits every segment and makes no random choice
/// of its own: the selection's flags and `--seed` are usage errors with it.
#[test]
fn selection_and_seed_flags_are_rejected_with_eiv() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(10));
    let p = p.to_str().expect("utf8");
    let o = odocal(&["calibrate", p, "--min-yaw-rate", "0.2"]);
    assert_usage_error(
        &o,
        &["--min-yaw-rate applies to the segment-selecting methods (three-step, batch-gn), not to --method eiv"],
    );
    let o = odocal(&["calibrate", p, "--method", "eiv", "--seed", "2"]);
    assert_usage_error(&o, &["--seed applies to --method three-step only, not to --method eiv"]);
    let o = odocal(&["calibrate", p, "--method", "batch-gn", "--seed", "2"]);
    assert_usage_error(&o, &["--seed applies to --method three-step only, not to --method batch-gn"]);
}

#[test]
fn three_step_flags_are_rejected_with_batch_gn() {
    let d = tempfile::tempdir().expect("tmp");
    let p = write(d.path(), "d.csv", &good_rows(10));
    let o = odocal(&["calibrate", p.to_str().expect("utf8"), "--method", "batch-gn", "--batches", "4"]);
    assert_usage_error(&o, &["--batches applies to --method three-step only, not to --method batch-gn"]);
    let o = odocal(&[
        "calibrate",
        p.to_str().expect("utf8"),
        "--method",
        "batch-gn",
        "--picks",
        "3",
        "--qp-solver",
        "clarabel",
    ]);
    assert_usage_error(&o, &["--picks, --qp-solver apply to --method three-step only"]);
    let o = odocal(&["calibrate", p.to_str().expect("utf8"), "--method", "batchgn"]);
    assert_eq!(o.status.code(), Some(2), "clap usage error: {}", stderr(&o));
    assert!(stderr(&o).contains("invalid method 'batchgn': use three-step, batch-gn or eiv"), "{}", stderr(&o));
    let o = odocal(&["calibrate", p.to_str().expect("utf8"), "--fix", "c_d,tr"]);
    assert!(
        stderr(&o).contains("invalid parameter 'tr': use c_e, c_d, t_r or d (or lever_x, lever_y, heading_offset)"),
        "{}",
        stderr(&o)
    );
}

#[test]
fn rejected_calibration_exits_3_and_still_writes_the_report() {
    let d = tempfile::tempdir().expect("tmp");
    let astr: &str = &simulated_drive(d.path(), "a.csv", &["--seed", "4", "--length-km", "3"]);
    // Another vehicle, [2.1, 1 mm, 1.66, 0]: θ_0 is closer in every parameter
    // than the calibrated ≈ [1.95, −2 mm, 1.53, 0.8 mm], so it wins on this drive.
    let bstr: &str =
        &simulated_drive(d.path(), "b.csv", &["--seed", "5", "--length-km", "3", "--theta", "2.1,0.001,1.66,0"]);
    let report = d.path().join("r.json");
    let args = ["calibrate", astr, "--method", "batch-gn", "--validate-on", bstr];
    let o = odocal(&[&args[..], &["--json", report.to_str().expect("utf8")]].concat());
    assert_eq!(o.status.code(), Some(3), "stderr: {}", stderr(&o));
    let out = stdout(&o);
    let after_table = out.split("d    mm/(m/s²)").nth(1).expect("θ table");
    let first = after_table.lines().nth(1).expect("a line after the table");
    assert_eq!(first, "  verdict: REJECTED", "{out}");
    assert!(out.contains("on the held-out data; per segment "), "{out}");
    assert!(out.contains("standard errors above 1: dead reckoning gets worse"), "{out}");
    let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&report).expect("r")).expect("json");
    assert_eq!(r["verdict"]["level"], "rejected");
    let worse = &r["verdict"]["reasons"][0];
    assert_eq!(worse["kind"], "worse_than_initial");
    // Every segment dead-reckons worse by a similar factor: far beyond the noise.
    assert!(worse["segment_ratio"].as_f64().expect("ratio") > 1.5, "{worse}");
    assert!(worse["segment_ratio_sigmas"].as_f64().expect("sigmas") > 3.0, "{worse}");
    // On its own drive the same calibration is not rejected: exit 0. It is
    // doubtful only for its σ: 3 km are too short for batch G-N's
    // cluster-robust σ.
    let o = odocal(&["calibrate", astr, "--method", "batch-gn"]);
    assert_eq!(o.status.code(), Some(0), "stderr: {}", stderr(&o));
    let out = stdout(&o);
    assert!(out.contains("  verdict: DOUBTFUL"), "{out}");
    assert!(out.contains("only the model σ of batch Gauss-Newton stands for this result"), "{out}");
}

/// The shipped van log (`data/psu-mapping-van-2024-07-11/`): on each
/// half-split, default `calibrate` (method eiv) either improves Ē_p over θ_0
/// on the held-out half and is not rejected, or ends `rejected` (exit code 3)
/// saying why; it is never accepted (the halves' t_r disagree). Measured:
/// EIV's checks fail on both halves and it falls back to its batch G-N start
/// (every segment, heading offset estimated). Holding out the first half gives Ē_p 23.6 m
/// against θ_0's 66.1 m, but t_r = 2.146 m lies beyond the plausible
/// 1.12–2.08 m: rejected as implausible. Holding out the second half gives
/// 26.0 m against 73.1 m (t_r 1.218 m), doubtful.
#[test]
#[ignore = "slow tier, a real-data claim (four calibrations of the van, ~5 s): cargo test --workspace -- --ignored"]
fn shipped_van_log_is_improved_or_rejected_on_both_half_splits() {
    let m = format!("{}/../../examples/psu-mapping-van/manifest.toml", env!("CARGO_MANIFEST_DIR"));
    let mut rejected = Vec::new();
    for half in ["first-half", "second-half"] {
        let o = odocal(&["calibrate", &m, "--holdout", half, "--json", "-"]);
        let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
        assert_eq!(r["method"], "eiv", "{half}: the default method");
        let (e, e0) = (
            r["validation"]["mean_position_error_m"].as_f64().expect("Ē_p"),
            r["initial"]["mean_position_error_m"].as_f64().expect("Ē_p θ_0"),
        );
        assert_eq!(r["validation"]["held_out"], true);
        let kinds: Vec<&str> =
            r["verdict"]["reasons"].as_array().expect("reasons").iter().filter_map(|x| x["kind"].as_str()).collect();
        if r["verdict"]["level"] == "rejected" {
            rejected.push(half);
            assert_eq!(o.status.code(), Some(3), "{half}: rejected must exit 3");
            if e >= e0 {
                assert!(kinds.contains(&"worse_than_initial"), "{half}: {kinds:?}");
            } else {
                assert!(kinds.contains(&"implausible"), "{half}: improved yet rejected must say why: {kinds:?}");
            }
        } else {
            assert!(e < e0, "{half}: not rejected, so Ē_p must improve on θ_0: {e} vs {e0}");
            assert_eq!(o.status.code(), Some(0), "{half}: {}", r["verdict"]);
        }
        // A fallback is said, with the check that failed.
        let warnings: Vec<&str> =
            r["warnings"].as_array().expect("warnings").iter().filter_map(|w| w["kind"].as_str()).collect();
        if r["eiv_result"] == "batch-gn-fallback" {
            assert!(warnings.contains(&"eiv_fallback") && warnings.contains(&"eiv_check_failed"), "{warnings:?}");
        }
        // The halves disagree (measured: t_r 2.146 vs 1.218 m): t_r is named.
        let doubts: Vec<&str> = r["verdict"]["reasons"]
            .as_array()
            .expect("reasons")
            .iter()
            .filter(|x| x["kind"] == "inconsistent_split" || x["kind"] == "large_uncertainty")
            .filter_map(|x| x["param"].as_str())
            .collect();
        assert!(doubts.contains(&"t_r"), "{half}: {}", r["verdict"]);
        assert_ne!(r["verdict"]["level"], "accepted", "{half}");
    }
    assert!(rejected.len() < 2, "measured: the second-half hold-out is kept (26.0 m against θ_0's 73.1 m)");
}

#[test]
fn several_drives_jointly_and_validation_on_several() {
    let d = tempfile::tempdir().expect("tmp");
    let paths: Vec<String> = [("a.csv", "4"), ("b.csv", "5"), ("c.csv", "6")]
        .iter()
        .map(|(n, seed)| simulated_drive(d.path(), n, &["--seed", seed, "--length-km", "2"]))
        .collect();
    let s: Vec<&str> = paths.iter().map(String::as_str).collect();
    // Validate on two drives, as a comma list and as a repeated flag: the same report.
    let list = format!("{},{}", s[1], s[2]);
    let o = odocal(&["calibrate", s[0], "--method", "batch-gn", "--validate-on", &list, "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let per = r["validate_on"]["drives"].as_array().expect("per drive");
    assert_eq!(per.len(), 2);
    assert_eq!(per[0]["name"], s[1]);
    let (e1, e2) =
        (per[0]["mean_position_error_m"].as_f64().expect("e"), per[1]["mean_position_error_m"].as_f64().expect("e"));
    let mean = r["validate_on"]["mean_over_drives_m"].as_f64().expect("mean");
    assert!((mean - (e1 + e2) / 2.0).abs() < 1e-12, "{mean} {e1} {e2}");
    // Each drive's Ē_p is what `validate` gives on it, δ held as batch G-N held it.
    let th = format!("{},{},{},{}", r["theta"]["c_e"], r["theta"]["c_d"], r["theta"]["t_r"], r["theta"]["d"]);
    let v = odocal(&["validate", s[2], "--theta", &th, "--carry-heading-offset", "--json", "-"]);
    let v: serde_json::Value = serde_json::from_slice(&v.stdout).expect("json");
    assert!((v["mean_position_error_m"].as_f64().expect("e") - e2).abs() < 1e-9);
    let o2 = odocal(&["calibrate", s[0], "--method", "batch-gn", "--validate-on", s[1], "--validate-on", s[2]]);
    assert!(o2.status.success(), "{}", stderr(&o2));
    let out = stdout(&o2);
    assert!(out.contains("validation drives (Ē_p calibrated / θ_0, m):"), "{out}");
    assert!(out.contains(&format!("  {}: {e1:.3} / ", s[1])), "{out}");
    // The mean of the drives' Ē_p and the mean over their segments (the
    // report's held-out Ē_p), each labelled, each as the JSON has it.
    let (n, ep) = (
        r["validation"]["segments"].as_u64().expect("n"),
        r["validation"]["mean_position_error_m"].as_f64().expect("Ē_p"),
    );
    assert!(out.contains(&format!("  mean of the 2 drives' Ē_p (each drive weighs the same): {mean:.3} / ")), "{out}");
    let over =
        format!("  mean over their {n} segments (each segment weighs the same; the Ē_p of the report): {ep:.3} / ");
    assert!(out.contains(&over), "{out}");
    assert!(out.contains(&format!("mean position error Ē_p on {n} validation segments of held-out data")), "{out}");
    assert!(out.contains(&format!("  calibrated   {ep:>9.3} m")), "{out}");

    // Two drives fitted jointly: more segments than either alone.
    let one = odocal(&["calibrate", s[0], "--method", "batch-gn", "--json", "-"]);
    let one: serde_json::Value = serde_json::from_slice(&one.stdout).expect("json");
    let both = odocal(&["calibrate", s[0], s[1], "--method", "batch-gn", "--json", "-"]);
    assert!(both.status.success(), "{}", stderr(&both));
    let both: serde_json::Value = serde_json::from_slice(&both.stdout).expect("json");
    assert!(
        both["segments"]["cut"].as_u64() > one["segments"]["cut"].as_u64(),
        "{} vs {}",
        both["segments"],
        one["segments"]
    );
    // …and each fitted alone too: their random-effects pooling gives the
    // between-drive part of the σ for the next drive.
    let next = &both["next_drive_sigma"];
    assert_eq!(next["between_source"], "random-effects", "{next}");
    assert_eq!(next["pooled"]["theta"].as_array().map(Vec::len), Some(2), "{next}");
    assert_eq!(one["next_drive_sigma"]["between_source"], "prior");
    let tau = next["pooled"]["params"][0]["tau"].as_f64().expect("τ of c_e");
    let between = next["between_drive"][0].as_f64().expect("between-drive σ of c_e");
    assert!(between >= tau, "{between} < {tau}");
    assert_eq!(both["sigma"]["c_e"], next["sigma"][0]);
    let text = stdout(&odocal(&["calibrate", s[0], s[1], "--method", "batch-gn"]));
    assert!(text.contains("  between drives (2 drives, each fitted alone with batch-gn;"), "{text}");
    assert!(text.contains("between-drive (2 drives pooled)"), "{text}");
    // Drives of different sample rates are not fitted together.
    let slow = d.path().join("slow.csv");
    let mut rows = String::from("t,px,py,psi,n_rl,n_rr,beta,a_y\n");
    for i in 0..40 {
        rows.push_str(&format!("{},{},0,0,5,5,0,0\n", i as f64 * 0.05, i as f64 * 0.5));
    }
    std::fs::write(&slow, rows).expect("write");
    let o = odocal(&["calibrate", s[0], slow.to_str().expect("utf8")]);
    assert_error(&o, &["drive 2 has a sample time of 0.050000 s, drive 1 0.025000 s"]);
}
