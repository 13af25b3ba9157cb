//! A manifest's `[noise]` and `[reference]` tables in `odocal calibrate`:
//! used where no flag is given, overridden by `--noise-model`,
//! `--estimate`, and the report says which was used.

use std::path::Path;
use std::process::{Command, Output};

fn odocal(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_odocal")).args(args).arg("--quiet").output().expect("run odocal")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// A manifest importing a simulated canonical CSV (both streams from it).
const MANIFEST: &str = r#"
[output]
clock_offset = 0.0
min_part_s = 1.0

[streams.d]
file = "drive.csv"
time_column = "t"

[wheels]
stream = "d"
signal = "rev_per_s"
rear_left = { column = "n_rl" }
rear_right = { column = "n_rr" }

[pose]
stream = "d"
position = { kind = "local", x = "px", y = "py" }
heading = { column = "psi", convention = "enu" }

[lateral_acceleration]
source = "imu"
stream = "d"
column = "a_y"

[noise]
wheel_white_rel_sigma = 0.011
wheel_common_rel_sigma = 0.0001

[reference]
lever_arm = [0.0, 0.0]
estimate = ["heading-offset"]
"#;

fn calibrate(dir: &Path, extra: &[&str]) -> serde_json::Value {
    let m = dir.join("manifest.toml");
    let mut args = vec!["calibrate", m.to_str().expect("utf8"), "--json", "-"];
    args.extend_from_slice(extra);
    let o = odocal(&args);
    assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", text(&o.stderr));
    serde_json::from_slice(&o.stdout).expect("json")
}

fn outcome(r: &serde_json::Value, key: &str) -> String {
    let uses = r["manifest_settings"].as_array().expect("manifest_settings");
    let u = uses.iter().find(|u| u["key"] == key).unwrap_or_else(|| panic!("no {key} in {uses:?}"));
    u["outcome"].as_str().expect("outcome").to_string()
}

#[test]
fn manifest_noise_and_reference_settings_are_used_unless_a_flag_is_given() {
    let d = tempfile::tempdir().expect("tmp");
    let drive = d.path().join("drive.csv");
    let o = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(["simulate", "--seed", "4", "--length-km", "2", "--noise", "white", "--quiet", "--out"])
        .arg(&drive)
        .output()
        .expect("run odocal");
    assert!(o.status.success(), "{}", text(&o.stderr));
    std::fs::write(d.path().join("manifest.toml"), MANIFEST).expect("write");

    // EIV: the manifest's [noise] is the start; the [reference] estimate is
    // used (two-stage: the batch G-N start estimates it, the filter holds it).
    let eiv = ["--method", "eiv", "--eiv-window", "1500", "--fix-noise", "--no-fallback"];
    let r = calibrate(d.path(), &eiv);
    assert_eq!(r["noise_start"]["wheel_white_rel_sigma"], 0.011, "{}", r["noise_start"]);
    assert!(
        r["noise_model_origin"].as_str().is_some_and(|s| s.starts_with("[noise] of ")),
        "{}",
        r["noise_model_origin"]
    );
    assert_eq!(outcome(&r, "noise"), "used");
    assert_eq!(outcome(&r, "reference.estimate"), "used");
    assert_eq!(r["extrinsics"]["free"], serde_json::json!(["heading_offset"]), "{}", r["extrinsics"]);
    let kinds: Vec<&str> =
        r["warnings"].as_array().expect("warnings").iter().filter_map(|w| w["kind"].as_str()).collect();
    assert!(kinds.contains(&"eiv_extrinsics_held") || kinds.contains(&"eiv_fallback"), "{kinds:?}");

    // --noise-model wins.
    let file = d.path().join("noise.toml");
    std::fs::write(&file, "wheel_white_rel_sigma = 0.009\n").expect("write");
    let mut args = eiv.to_vec();
    args.extend(["--noise-model", file.to_str().expect("utf8")]);
    let r = calibrate(d.path(), &args);
    assert_eq!(r["noise_start"]["wheel_white_rel_sigma"], 0.009);
    assert!(r["noise_model_origin"].as_str().is_some_and(|s| s.starts_with("--noise-model ")));
    assert_eq!(outcome(&r, "noise"), "overridden");

    // Batch G-N: the [reference] estimate is used; --estimate wins.
    let r = calibrate(d.path(), &["--method", "batch-gn"]);
    assert_eq!(outcome(&r, "reference.estimate"), "used");
    assert_eq!(outcome(&r, "noise"), "ignored");
    assert!(r["noise_model_origin"].is_null());
    assert_eq!(r["extrinsics"]["free"], serde_json::json!(["heading_offset"]), "{}", r["extrinsics"]);
    let r = calibrate(d.path(), &["--method", "batch-gn", "--estimate", "lever-arm"]);
    assert_eq!(outcome(&r, "reference.estimate"), "overridden");
    assert_eq!(r["extrinsics"]["free"], serde_json::json!(["lever_x", "lever_y"]), "{}", r["extrinsics"]);
}
