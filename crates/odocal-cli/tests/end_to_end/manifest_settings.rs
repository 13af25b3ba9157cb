//! A manifest's `[noise]` and `[reference]` tables in `odocal calibrate`:
//! used where no flag is given, overridden by `--noise-model`,
//! `--estimate`, and the report says which was used.

use crate::common;

use std::path::Path;

use common::{calibrate_json, canonical_manifest, setting_outcome};

/// A manifest importing a simulated canonical CSV (both streams from it)
/// that states a noise model and the reference extrinsics.
fn manifest() -> String {
    canonical_manifest(
        "drive.csv",
        r#"
[noise]
wheel_white_rel_sigma = 0.011
wheel_common_rel_sigma = 0.0001

[reference]
lever_arm = [0.0, 0.0]
estimate = ["heading-offset"]
"#,
    )
}

fn calibrate(dir: &Path, extra: &[&str]) -> serde_json::Value {
    calibrate_json(&dir.join("manifest.toml"), extra)
}

#[test]
fn manifest_noise_and_reference_settings_are_used_unless_a_flag_is_given() {
    let d = tempfile::tempdir().expect("tmp");
    common::simulated_drive(d.path(), "drive.csv", &["--seed", "4", "--length-km", "2", "--noise", "white"]);
    std::fs::write(d.path().join("manifest.toml"), manifest()).expect("write");

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
    assert_eq!(setting_outcome(&r, "noise"), "used");
    assert_eq!(setting_outcome(&r, "reference.estimate"), "used");
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
    assert_eq!(setting_outcome(&r, "noise"), "overridden");

    // Batch G-N: the [reference] estimate is used; --estimate wins.
    let r = calibrate(d.path(), &["--method", "batch-gn"]);
    assert_eq!(setting_outcome(&r, "reference.estimate"), "used");
    assert_eq!(setting_outcome(&r, "noise"), "ignored");
    assert!(r["noise_model_origin"].is_null());
    assert_eq!(r["extrinsics"]["free"], serde_json::json!(["heading_offset"]), "{}", r["extrinsics"]);
    let r = calibrate(d.path(), &["--method", "batch-gn", "--estimate", "lever-arm"]);
    assert_eq!(setting_outcome(&r, "reference.estimate"), "overridden");
    assert_eq!(r["extrinsics"]["free"], serde_json::json!(["lever_x", "lever_y"]), "{}", r["extrinsics"]);
}

/// `[calibration] theta0` naming a parameter file: the file beside the
/// manifest is read whatever the working directory (the test runs from the
/// crate's folder, where no such file is), and it is an input no output may
/// overwrite.
#[test]
fn a_manifest_theta0_file_is_relative_to_the_manifest_and_protected() {
    let d = tempfile::tempdir().expect("tmp");
    common::simulated_drive(d.path(), "drive.csv", &["--seed", "4", "--length-km", "2", "--noise", "white"]);
    // A parameter file with this drive's batch G-N θ: a θ_0 that no default equals.
    let t0 = d.path().join("t0.yaml");
    let o = common::odocal(&[
        "calibrate",
        common::s(&d.path().join("drive.csv")),
        "--method",
        "batch-gn",
        "--params-out",
        common::s(&t0),
    ]);
    assert!(o.status.success(), "{}", common::stderr(&o));
    let written = std::fs::read(&t0).expect("t0.yaml");
    let expected = calibrate_json(&d.path().join("drive.csv"), &["--method", "batch-gn"])["theta"].clone();
    std::fs::write(
        d.path().join("manifest.toml"),
        canonical_manifest("drive.csv", "[calibration]\ntheta0 = \"t0.yaml\"\n"),
    )
    .expect("write");
    assert!(!Path::new("t0.yaml").exists(), "the test needs a working directory without t0.yaml");

    let r = calibrate(d.path(), &["--method", "batch-gn"]);
    assert_eq!(r["initial"]["theta"], expected, "θ_0 is not the file's: {}", r["initial"]);
    assert_eq!(setting_outcome(&r, "calibration.theta0"), "used");

    // --params-out onto it is refused before any work, and the file is intact.
    let e = common::assert_fails(
        &["calibrate", common::s(&d.path().join("manifest.toml")), "--params-out", common::s(&t0)],
        1,
        &["theta0 parameter file"],
    );
    assert!(e.contains("t0.yaml"), "{e}");
    assert_eq!(std::fs::read(&t0).expect("t0.yaml"), written);
}
