//! Helpers shared by the end-to-end tests of the `odocal` binary (each test
//! module uses a subset, hence `dead_code` allowed).
#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

use serde_json::Value;

/// Runs the `odocal` binary of this build with `args` and `--quiet`.
pub fn odocal(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_odocal")).args(args).arg("--quiet").output().expect("run odocal")
}

/// [`odocal`] run in the folder `dir`.
pub fn odocal_in(dir: &std::path::Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_odocal")).current_dir(dir).args(args).arg("--quiet").output().expect("run odocal")
}

/// Bytes of stdout or stderr as text (lossy).
pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The run's stderr as text.
pub fn stderr(o: &Output) -> String {
    text(&o.stderr)
}

/// The run's stdout as text.
pub fn stdout(o: &Output) -> String {
    text(&o.stdout)
}

/// `odocal simulate ARGS… --out DIR/NAME`, asserting that it ran: the
/// simulated drive's CSV path as text (its sidecar JSON is beside it).
pub fn simulated_drive(dir: &Path, name: &str, args: &[&str]) -> String {
    let out = dir.join(name).to_str().expect("utf8").to_owned();
    let mut all = vec!["simulate"];
    all.extend_from_slice(args);
    all.extend(["--out", &out]);
    let o = odocal(&all);
    assert!(o.status.success(), "{}", stderr(&o));
    out
}

/// A manifest importing the canonical CSV `file` (relative to the
/// manifest) for every stream — wheels in rev/s, local pose with ENU
/// heading, a_y as an IMU signal — with `extra` (more TOML tables)
/// appended.
pub fn canonical_manifest(file: &str, extra: &str) -> String {
    format!(
        r#"
[output]
clock_offset = 0.0
min_part_s = 1.0

[streams.d]
file = "{file}"
time_column = "t"

[wheels]
stream = "d"
signal = "rev_per_s"
rear_left = {{ column = "n_rl" }}
rear_right = {{ column = "n_rr" }}

[pose]
stream = "d"
position = {{ kind = "local", x = "px", y = "py" }}
heading = {{ column = "psi", convention = "enu" }}

[lateral_acceleration]
source = "imu"
stream = "d"
column = "a_y"
{extra}"#
    )
}

/// `odocal calibrate INPUT ARGS… --json -`: asserts it ran (exit 0, or 3
/// for a rejected result) and returns the JSON report.
pub fn calibrate_json(input: &Path, args: &[&str]) -> Value {
    let mut all = vec!["calibrate", input.to_str().expect("utf8")];
    all.extend_from_slice(args);
    all.extend(["--json", "-"]);
    let o = odocal(&all);
    assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", stderr(&o));
    serde_json::from_slice(&o.stdout).expect("json")
}

/// What became of the manifest setting `key` (`used`, `overridden`, …) in
/// a calibrate report's `manifest_settings`.
pub fn setting_outcome(r: &Value, key: &str) -> String {
    let uses = r["manifest_settings"].as_array().expect("manifest_settings");
    let u = uses.iter().find(|u| u["key"] == key).unwrap_or_else(|| panic!("no {key} in {uses:?}"));
    u["outcome"].as_str().expect("outcome").to_string()
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> &str {
    p.to_str().expect("utf8")
}

/// Runs `odocal args`, asserts it exits with `code`, prints nothing on
/// stdout and says each of `needles` on stderr; returns stderr.
pub fn assert_fails(args: &[&str], code: i32, needles: &[&str]) -> String {
    let o = odocal(args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(code), "{args:?}: {e}");
    assert!(o.stdout.is_empty(), "{args:?}: stdout {:?}", String::from_utf8_lossy(&o.stdout));
    for n in needles {
        assert!(e.contains(n), "{args:?}: '{n}' not in: {e}");
    }
    e
}
