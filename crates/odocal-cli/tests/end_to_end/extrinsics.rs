//! The reference-extrinsics flags of `odocal calibrate`: `--estimate`,
//! `--lever-arm`, `--heading-offset`, `--fix` of an extrinsics parameter,
//! and their rows in the JSON, terminal and parameter-file reports.

use crate::common;

use std::process::Output;

use common::odocal;
use serde_json::Value;

fn json(o: &Output) -> Value {
    assert!(o.status.code().is_some_and(|c| c == 0 || c == 3), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).expect("json on stdout")
}

#[test]
fn estimate_hold_and_fix_extrinsics() {
    let dir = tempfile::tempdir().expect("tmp");
    let drive = common::simulated_drive(
        dir.path(),
        "d.csv",
        &["--seed", "5", "--length-km", "3", "--noise", "off", "--substeps", "1"],
    );
    let d = drive.as_str();

    // Without the flags the report has no extrinsics block.
    let plain = json(&odocal(&["calibrate", d, "--method", "batch-gn", "--json", "-"]));
    assert!(plain.get("extrinsics").is_none(), "{}", plain["extrinsics"]);

    // Estimated: the noise-free simulated reference is at the axle (0). (Under
    // paper noise the G-N σ is far too small for the extrinsics: see
    // extrinsics_check in crates/odocal-lab.)
    let est = json(&odocal(&[
        "calibrate",
        d,
        "--method",
        "batch-gn",
        "--estimate",
        "lever-arm,heading-offset",
        "--json",
        "-",
    ]));
    let x = &est["extrinsics"];
    assert_eq!(x["free"], serde_json::json!(["lever_x", "lever_y", "heading_offset"]), "{x}");
    for p in ["lever_x", "lever_y", "heading_offset"] {
        let (v, s) = (x["value"][p].as_f64().expect("value"), x["std_dev"][p].as_f64().expect("σ"));
        assert!(s.is_finite() && v.abs() < 1e-6, "{p} = {v} ± {s}");
    }
    assert_eq!(est["options"]["identify"]["free"].as_array().map(Vec::len), Some(7), "{}", est["options"]);

    // Held at a given value, one of them estimated, one held by --fix.
    let o = odocal(&[
        "calibrate",
        d,
        "--method",
        "batch-gn",
        "--lever-arm",
        "-0.5,0",
        "--heading-offset",
        "0.002",
        "--estimate",
        "heading-offset,lever_x",
        "--fix",
        "lever_x",
    ]);
    assert!(o.status.code().is_some_and(|c| c == 0 || c == 3), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("reference extrinsics"), "{text}");
    let l_x = text.lines().find(|l| l.trim_start().starts_with("l_x")).expect("l_x row");
    assert!(l_x.contains("-0.5000") && l_x.contains("held"), "{l_x}");

    // The parameter file carries them.
    let params = dir.path().join("p.json");
    let o = odocal(&[
        "calibrate",
        d,
        "--method",
        "batch-gn",
        "--estimate",
        "heading-offset",
        "--params-out",
        params.to_str().expect("utf8"),
    ]);
    assert!(o.status.code().is_some_and(|c| c == 0 || c == 3), "{}", String::from_utf8_lossy(&o.stderr));
    let p: Value = serde_json::from_str(&std::fs::read_to_string(&params).expect("params")).expect("json");
    assert!(p["parameters"]["heading_offset_sigma"].as_f64().is_some(), "{p}");
    assert_eq!(p["parameters"]["lever_x_held"], true, "{p}");

    // Bad flags: one-line errors; the flags the settings refuse are usage errors.
    let o = odocal(&["calibrate", d, "--estimate", "c_e"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--estimate takes lever-arm, heading-offset"));
    let o = odocal(&["calibrate", d, "--lever-arm", "1"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--lever-arm takes X,Y"));
}

/// The default method's note that its filter held the extrinsics its start
/// estimated prints as `note:`, not as a warning; the JSON lists it with
/// the warnings by kind.
#[test]
fn held_extrinsics_print_as_a_note() {
    let dir = tempfile::tempdir().expect("tmp");
    let drive = common::simulated_drive(dir.path(), "d.csv", &["--seed", "3", "--length-km", "6", "--substeps", "1"]);
    let o = odocal(&["calibrate", drive.as_str(), "--json", "-"]);
    let stderr = String::from_utf8_lossy(&o.stderr).to_string();
    let report = json(&o);
    let kinds: Vec<&str> =
        report["warnings"].as_array().expect("warnings").iter().filter_map(|w| w["kind"].as_str()).collect();
    assert!(kinds.contains(&"eiv_extrinsics_held"), "{kinds:?}\n{stderr}");
    assert!(stderr.contains("note: EIV two-stage"), "{stderr}");
    assert!(!stderr.contains("warning: EIV two-stage"), "{stderr}");
}
