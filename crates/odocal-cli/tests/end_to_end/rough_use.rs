//! A careless user's command lines and files: each ends with an error that
//! names the option, file or key and what to do, before any work where the
//! problem is in the command line, and never with a misleading hint.

use crate::common::{assert_fails, odocal, s, stderr};

/// An output in a folder that exists but takes no files (here `/proc`; a
/// folder without write permission or on a read-only file system alike) is
/// named before the work, not after it when the result would be lost: the
/// drive here is empty, and its error would come first if the work started.
#[test]
#[cfg(target_os = "linux")]
fn an_output_folder_that_takes_no_files_is_named_before_any_work() {
    let dir = tempfile::tempdir().expect("tmp");
    let empty = dir.path().join("empty.csv");
    std::fs::write(&empty, "").expect("write");
    for option in ["--json", "--report", "--params-out"] {
        let out = format!("/proc/odocal-never-written.{}", if option == "--report" { "html" } else { "json" });
        let e = assert_fails(
            &["calibrate", s(&empty), option, &out],
            1,
            &[&format!("{option} {out}: cannot create a file in the folder /proc"), "give a folder you can write to"],
        );
        assert!(!e.contains("empty.csv") && !e.contains(".tmp"), "{e}");
    }
    let db = dir.path().join("h.sqlite");
    assert_fails(
        &["follow", s(&empty), "--vehicle", "v", "--db", s(&db), "--params-out", "/proc/x.yaml"],
        1,
        &["--params-out /proc/x.yaml: cannot create a file in the folder /proc"],
    );
    assert!(!db.exists(), "the history was created before the outputs were checked");
}

/// `inspect --manifest` onto the bag itself or onto a folder says so, not
/// "exists; … --force", which would not help.
#[test]
fn a_draft_manifest_onto_the_bag_or_a_folder_does_not_suggest_force() {
    let dir = tempfile::tempdir().expect("tmp");
    let bag = dir.path().join("drive.mcap");
    std::fs::write(&bag, b"not read: the outputs are checked first").expect("write");
    for (out, needle) in [(s(&bag), "is also the bag"), (s(dir.path()), "is a directory")] {
        let e = assert_fails(&["inspect", s(&bag), "--manifest", out], 1, &[&format!("--manifest {out}"), needle]);
        assert!(!e.contains("--force"), "{e}");
    }
}

/// A blank vehicle identifier, or one with a space at an end (a vehicle of
/// its own in the history), is a usage error before the history is opened.
#[test]
fn a_blank_or_padded_vehicle_id_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let db = dir.path().join("h.sqlite");
    for (id, needle) in [("", "is empty"), ("  ", "is empty"), ("van-1 ", "a space at an end"), ("van\n1", "control")] {
        assert_fails(&["calibrate", "d.csv", "--vehicle", id, "--db", s(&db)], 2, &["--vehicle", needle]);
        assert_fails(&["follow", "d.csv", "--vehicle", id, "--db", s(&db)], 2, &["--vehicle", needle]);
    }
    assert!(!db.exists());
}

/// A drift that would simulate a vehicle that cannot exist (c_e a billion
/// times larger by the end, a c_d step in metres) or a c_d step after the
/// drive's end is a usage error naming the flags; nothing is written.
#[test]
fn an_implausible_simulated_drift_is_a_usage_error() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("d.csv");
    let sim = |flag: &'static str, value: &'static str| ["simulate", "--length-km", "1", "--out", s(&out), flag, value];
    // Each error names the flag given, not both.
    let e = assert_fails(&sim("--ce-ramp-per-hour", "1e9"), 2, &["--ce-ramp-per-hour: ", "c_e = ", "outside"]);
    assert!(!e.contains("--cd-step"), "{e}");
    let e = assert_fails(&sim("--cd-step", "1000@10"), 2, &["--cd-step: ", "|c_d|"]);
    assert!(!e.contains("--ce-ramp-per-hour"), "{e}");
    assert_fails(&sim("--cd-step", "0.5@1e9"), 2, &["the c_d step at 1e9 s comes after the drive's end"]);
    assert!(!out.exists());
}

/// A drive in which the vehicle never moves: c_e is not observable, and the
/// error says to check the drive instead of suggesting a command that holds
/// c_d, t_r, d (which fails alike) or --auto-fix (already given).
#[test]
fn a_drive_that_never_moves_gets_no_command_that_fails_alike() {
    let dir = tempfile::tempdir().expect("tmp");
    let still = dir.path().join("still.csv");
    let rows: String = (0..3000).map(|i| format!("{},0,0,0,0,0,0,0\n", f64::from(i) * 0.025)).collect();
    std::fs::write(&still, format!("t,px,py,psi,n_rl,n_rr,beta,a_y\n{rows}")).expect("write");
    for extra in [&[][..], &["--method", "batch-gn", "--auto-fix"][..]] {
        let args = [&["calibrate", s(&still)][..], extra].concat();
        let e = assert_fails(&args, 1, &["c_e", "not observable", "check that the vehicle moves"]);
        assert!(!e.contains("run: odocal") && !e.contains("--auto-fix"), "{e}");
    }
}

/// A `--validate-on` drive that fails the checks of its conventions is
/// named, not called "held-out drive".
#[test]
fn a_bad_validation_drive_is_named() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = crate::common::simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    // Another drive with its wheel readings doubled: the wheels turn twice too fast for the reference.
    let e = crate::common::simulated_drive(dir.path(), "e.csv", &["--length-km", "2", "--seed", "5"]);
    let text = std::fs::read_to_string(&e).expect("read");
    let mut lines = text.lines();
    let header = lines.next().expect("header");
    let wheels: Vec<usize> =
        header.split(',').enumerate().filter(|(_, h)| *h == "n_rl" || *h == "n_rr").map(|(i, _)| i).collect();
    assert_eq!(wheels.len(), 2, "{header}");
    let mut slow = format!("{header}\n");
    for l in lines {
        let row: Vec<String> = l
            .split(',')
            .enumerate()
            .map(|(i, v)| if wheels.contains(&i) { (2.0 * v.parse::<f64>().expect("n")).to_string() } else { v.into() })
            .collect();
        slow.push_str(&(row.join(",") + "\n"));
    }
    let bad = dir.path().join("slow.csv");
    std::fs::write(&bad, slow).expect("write");
    let e = assert_fails(
        &["calibrate", &d, "--method", "batch-gn", "--validate-on", s(&bad)],
        1,
        &[&format!("--validate-on {}: the wheel speed at θ_0", s(&bad))],
    );
    assert!(!e.contains("held-out drive"), "{e}");
}

/// A drive too short for one segment is named, with the option that
/// shortens the segments.
#[test]
fn a_drive_too_short_for_a_segment_is_named_with_the_option() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = crate::common::simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    assert_fails(
        &["calibrate", &d, "--method", "batch-gn", "--segment-length", "100000"],
        1,
        &[&format!("{d}: no usable segments"), "needs 100001 samples", "--segment-length"],
    );
    assert_fails(
        &["validate", &d, "--theta", "2,0,1.6,0", "--validation-length", "100000"],
        1,
        &[&format!("{d}: no usable segments"), "--validation-length"],
    );
}

/// `compensate --out -`: the CSV on stdout, the summary on stderr saying
/// where the drive went (it said "wrote -").
#[test]
fn compensate_to_stdout_says_so_on_stderr() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = crate::common::simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let o = odocal(&["compensate", &d, "--theta", "1.95,-0.002,1.53,0.0008", "--out", "-"]);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(crate::common::stdout(&o).starts_with("t,px,py,psi,"), "the CSV on stdout");
    assert!(e.contains("wrote the compensated drive to stdout: ") && !e.contains("wrote -"), "{e}");
}

/// `inspect -` says a bag is read from a file (it said "-: No such file
/// or directory").
#[test]
fn a_bag_from_stdin_is_refused_saying_why() {
    let e = assert_fails(&["inspect", "-"], 1, &["-: a bag is read from a file, not from stdin", "save it first"]);
    assert!(!e.contains("No such file"), "{e}");
}

/// `--params-node` that ROS 2 would not load (empty, a dash, a space) is a
/// usage error before the work; a namespaced name is taken.
#[test]
fn a_params_node_ros_2_would_not_load_is_refused() {
    for node in ["", "my-node", "a b"] {
        assert_fails(
            &["calibrate", "d.csv", "--params-out", "p.yaml", "--params-node", node],
            2,
            &["--params-node", "is not a ROS 2 node name"],
        );
    }
    let dir = tempfile::tempdir().expect("tmp");
    let d = crate::common::simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let p = dir.path().join("p.yaml");
    let o = odocal(&["calibrate", &d, "--method", "batch-gn", "--params-out", s(&p), "--params-node", "/van/odometry"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read_to_string(&p).expect("read").contains("/van/odometry:\n  ros__parameters:"));
}

/// `--min-yaw-rate nan` is a usage error naming the flag (calibrate said
/// "invalid option `min_peak_yaw_rate_rad_per_s`" after the import, follow
/// alike after opening the history).
#[test]
fn a_min_yaw_rate_that_is_not_a_rate_is_a_usage_error() {
    let dir = tempfile::tempdir().expect("tmp");
    let db = dir.path().join("h.sqlite");
    for cmd in
        [&["calibrate", "d.csv", "--method", "batch-gn"][..], &["follow", "d.csv", "--vehicle", "v", "--db", s(&db)]]
    {
        let args = [cmd, &["--min-yaw-rate", "nan"][..]].concat();
        let e = assert_fails(&args, 2, &["--min-yaw-rate", "'nan' is not a non-negative number of rad/s"]);
        assert!(!e.contains("min_peak"), "{e}");
    }
    assert!(!db.exists());
}

/// `--json /dev/stdout` with stdout on a pipe (as here, where the test
/// reads the output) is `--json -`: the JSON alone on stdout, not a file
/// to replace in the link's folder `/proc/self/fd`. `/dev/stderr` is
/// written in place.
#[cfg(target_os = "linux")]
#[test]
fn an_output_onto_dev_stdout_or_stderr_on_a_pipe_is_written() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = crate::common::simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    let o = odocal(&["validate", &d, "--theta", "1.95,-0.002,1.53,0.0008", "--json", "/dev/stdout"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("the JSON report alone on stdout");
    assert!(v["mean_position_error_m"].is_number(), "{v}");
    let o = odocal(&["validate", &d, "--theta", "1.95,-0.002,1.53,0.0008", "--json", "/dev/stderr"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("\"mean_position_error_m\""), "{}", stderr(&o));
}

/// `simulate --out /dev/null`: refused before any work, saying why (the
/// sidecar has no folder beside a device: no file /dev/null.json).
#[cfg(unix)]
#[test]
fn a_simulated_drive_onto_a_device_is_refused() {
    let existed = std::path::Path::new("/dev/null.json").exists();
    assert_fails(
        &["simulate", "--length-km", "1", "--out", "/dev/null"],
        1,
        &["--out /dev/null: not a file", "sidecar"],
    );
    assert_eq!(std::path::Path::new("/dev/null.json").exists(), existed, "no file beside the device");
}

/// A route length out of range is a usage error naming the flag, negative
/// ones included (not an unknown flag `-3`), and so is the simulator's
/// ceiling (not the library's "invalid option `length_km`").
#[test]
fn a_route_length_out_of_range_names_the_flag() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("d.csv");
    for (km, want) in [("-3", "must be a positive number of kilometres, got -3"), ("1e9", "--length-km: ")] {
        assert_fails(&["simulate", "--length-km", km, "--out", s(&out)], 2, &[want]);
        assert_fails(&["demo", "--length-km", km], 2, &[want]);
    }
    assert!(!out.exists());
}

/// `--auto-fix` holds what the fit itself finds not observable: on a
/// test-track run that turns one way the check at θ_0 passes, but the
/// default method's fit names t_r and d; they are held at θ_0 and the run
/// fitted again, so the result does not carry them as estimates it
/// calls untrustworthy.
#[test]
fn auto_fix_holds_what_the_fit_finds_not_observable() {
    let run = format!("{}/../../examples/psu-mapping-van-testtrack/run-14-45-26.toml", env!("CARGO_MANIFEST_DIR"));
    let plain = crate::common::calibrate_json(std::path::Path::new(&run), &[]);
    assert_eq!(plain["observability"]["unobservable"], serde_json::json!(["t_r", "d"]), "{}", plain["observability"]);
    let fixed = crate::common::calibrate_json(std::path::Path::new(&run), &["--auto-fix"]);
    assert_eq!(fixed["auto_fixed"], serde_json::json!(["t_r", "d"]), "{}", fixed["auto_fixed"]);
    assert_eq!(fixed["observability"]["unobservable"], serde_json::json!([]), "{}", fixed["observability"]);
    assert_eq!(fixed["theta"]["t_r"].as_f64(), Some(1.6));
    assert_eq!(fixed["theta"]["d"].as_f64(), Some(0.0));
    let codes: Vec<&str> =
        fixed["warnings"].as_array().expect("warnings").iter().filter_map(|w| w["kind"].as_str()).collect();
    assert!(codes.contains(&"auto_fix_refit"), "{codes:?}");
}
