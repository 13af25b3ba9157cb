//! One CLI test per class of bad input found by the bad-input issue: the
//! exit code (1 for bad data, 2 for a bad command line) and the one-line
//! message that names the cause; and import memory bounded on the
//! blow-up manifests (run under an address-space limit).

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::{odocal, stderr};

fn assert_fails(o: &Output, code: i32, needles: &[&str]) {
    let e = stderr(o);
    assert_eq!(o.status.code(), Some(code), "stderr: {e}");
    for n in needles {
        assert!(e.contains(n), "expected '{n}' in: {e}");
    }
}

fn corpus(kind: &str, name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus").join(kind).join(name)
}

fn path_str(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// Writes the sections of an import bundle into `dir`; returns the manifest.
fn unpack(bundle: &Path, dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(bundle).expect("bundle");
    for section in text.split("=== ").skip(1) {
        let (name, body) = section.split_once('\n').unwrap_or((section, ""));
        std::fs::write(dir.join(name.trim()), body).expect("write");
    }
    dir.join("m.toml")
}

#[test]
fn csv_classes_exit_1_with_the_cause() {
    for (file, needles) in [
        ("duplicate_t.csv", &["duplicate column name(s) t"][..]),
        ("time_ns.csv", &["microseconds or nanoseconds"]),
        ("time_tiny.csv", &["outside the plausible"]),
        ("wheels_1e300.csv", &["column 'n_rl'", "rev/s"]),
        ("px_1e308.csv", &["column 'px'"]),
        ("heading_degrees.csv", &["degrees"]),
        ("semicolon.csv", &["separated by ';'"]),
        ("part_float.csv", &["not a non-negative integer"]),
        ("long_field.csv", &["… (5000 bytes)"]),
        ("mcap_bag.csv", &["a ROS 2 bag (MCAP)", "odocal inspect", "manifest (.toml)"]),
        ("gzip.csv", &["gzip-compressed"]),
    ] {
        let o = odocal(&["calibrate", path_str(&corpus("csv_drive", file))]);
        assert_fails(&o, 1, needles);
        assert!(stderr(&o).len() < 600, "{file}: long message: {}", stderr(&o));
        assert_eq!(stderr(&o).trim_end().lines().count(), 1, "{file}: one line");
    }
}

/// A bag (named .mcap, as users have it) or a rosbag2 directory given where
/// a drive belongs: exit 1, saying what the file is and what to do.
#[test]
fn a_bag_given_as_the_drive_says_to_describe_it_in_a_manifest() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bag = dir.path().join("drive.mcap");
    std::fs::copy(corpus("csv_drive", "mcap_bag.csv"), &bag).expect("copy");
    let o = odocal(&["calibrate", path_str(&bag)]);
    assert_fails(&o, 1, &["drive.mcap: a ROS 2 bag (MCAP), not a canonical drive CSV", "odocal inspect"]);
    let bagdir = dir.path().join("rosbag2_run");
    std::fs::create_dir(&bagdir).expect("mkdir");
    std::fs::write(bagdir.join("metadata.yaml"), "rosbag2_bagfile_information:\n").expect("write");
    let o = odocal(&["validate", path_str(&bagdir), "--theta", "1.95,0,1.53,0"]);
    assert_fails(&o, 1, &["rosbag2_run: a ROS 2 bag directory", "manifest"]);
    let o = odocal(&["calibrate", path_str(dir.path())]);
    assert_fails(&o, 1, &["a directory, not a canonical drive CSV"]);
}

#[test]
fn text_in_extra_columns_is_accepted() {
    let o = odocal(&["validate", path_str(&corpus("csv_drive", "text_extra.csv")), "--theta", "2,0,1.6,0"]);
    // The drive is a straight line: it is read, and fails only for being too short to validate.
    assert!(!stderr(&o).contains("not a number"), "{}", stderr(&o));
}

#[test]
fn absurd_theta_is_a_usage_error() {
    let d = corpus("csv_drive", "valid.csv");
    for (theta, needle) in [("2,5,1.6,0", "c_d"), ("2,0,1e308,0", "t_r"), ("2,0,1.6,1", "|d|"), ("-2,0,1.6,0", "c_e")] {
        let o = odocal(&["validate", path_str(&d), "--theta", theta]);
        assert_fails(&o, 2, &[needle]);
        assert!(stderr(&o).contains("SI units") || stderr(&o).contains("positive"), "{}", stderr(&o));
    }
}

#[test]
fn conventions_are_named() {
    let dir = tempfile::tempdir().expect("tmp");
    let csv = common::simulated_drive(dir.path(), "d.csv", &["--seed", "2", "--length-km", "2"]);
    let text = std::fs::read_to_string(&csv).expect("csv");
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |n: &str| header.iter().position(|h| *h == n).expect("column");
    let (rl, rr) = (col("n_rl"), col("n_rr"));
    let mut out = header.join(",") + "\n";
    for l in lines {
        let mut f: Vec<String> = l.split(',').map(str::to_string).collect();
        for j in [rl, rr] {
            f[j] = format!("{}", -f[j].parse::<f64>().expect("number"));
        }
        out += &(f.join(",") + "\n");
    }
    let neg = dir.path().join("neg.csv");
    std::fs::write(&neg, out).expect("write");
    let o = odocal(&["calibrate", path_str(&neg), "--method", "batch-gn"]);
    assert_fails(&o, 1, &["wheels turn backwards"]);
}

#[test]
fn io_errors_are_not_doubled() {
    let dir = tempfile::tempdir().expect("tmp");
    let missing = dir.path().join("missing.csv");
    let o = odocal(&["calibrate", path_str(&missing)]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert_eq!(e.matches("No such file or directory").count(), 1, "{e}");
    assert_eq!(e.matches("missing.csv").count(), 1, "{e}");
}

/// The blow-up manifests end in an error, within 2 GB of address space (read
/// as they ask, they would take 3–480 GB) and a generous time limit.
#[test]
#[cfg(target_os = "linux")]
fn import_blow_ups_stay_bounded() {
    for name in [
        "rate_i64max.bundle",
        "rate_1e9.bundle",
        "rate_1e6.bundle",
        "wheel_time_us.bundle",
        "wheel_time_x1000.bundle",
        "max_clock_offset_1e5.bundle",
        "dejitter_window_1e9.bundle",
        "nominal_rate_1e7.bundle",
        "counter_bits_8.bundle",
        "rev_per_s_on_ticks.bundle",
        "latlon_metres.bundle",
        "wheels_negated.bundle",
    ] {
        let dir = tempfile::tempdir().expect("tmp");
        let m = unpack(&corpus("import", name), dir.path());
        let out = dir.path().join("o.csv");
        let script = format!(
            "ulimit -v 2000000; exec timeout 120 '{}' import '{}' --out '{}' --quiet",
            env!("CARGO_BIN_EXE_odocal"),
            path_str(&m),
            path_str(&out)
        );
        let o = Command::new("bash").arg("-c").arg(&script).output().expect("bash");
        assert_fails(&o, 1, &["error: "]);
        assert!(!out.exists(), "{name}: no drive written");
    }
}

/// A segment length or stride too small to cut a segment is a bad command
/// line naming the option, not the library's field (`length_steps` for
/// both lengths); the drive is not read.
#[test]
fn segment_options_too_small_name_the_option() {
    let theta = ["--theta", "1.95,0,1.5,0"];
    for (args, option) in [
        (vec!["calibrate", "missing.csv", "--validation-length", "1"], "--validation-length <"),
        (vec!["calibrate", "missing.csv", "--segment-length", "0"], "--segment-length <"),
        (vec!["calibrate", "missing.csv", "--segment-stride", "0"], "--segment-stride <"),
        ([&["validate", "missing.csv"][..], &theta, &["--validation-length", "1"]].concat(), "--validation-length <"),
        (
            [&["compensate", "missing.csv"][..], &theta, &["--out", "x.csv", "--segment-length", "1"]].concat(),
            "--segment-length <",
        ),
    ] {
        let o = odocal(&args);
        assert_fails(&o, 2, &[option, "must be at least"]);
        assert!(!stderr(&o).contains("length_steps") && !stderr(&o).contains("stride_steps"), "{}", stderr(&o));
    }
}
