//! `calibrate --validate-on` applies a validation drive's own `[reference]`
//! (odocal::assess::validation_drives): a noise-free simulated drive whose pose reference sits at a
//! known lever arm and heading offset, read through a manifest stating
//! them, validates with a lower Ē_p than the same drive as a bare CSV; the
//! report says which extrinsics each drive used; a command-line value that
//! overrules the drive's is reported as a conflict.

use crate::common;

use std::path::Path;

use common::{calibrate_json, canonical_manifest, odocal, text};
use odocal::sim::{simulate, SimOptions};
use odocal::Extrinsics;

fn calibrate(fit: &Path, extra: &[&str]) -> serde_json::Value {
    calibrate_json(fit, &[&["--method", "batch-gn"], extra].concat())
}

#[test]
fn a_validation_drive_applies_its_own_reference() {
    let d = tempfile::tempdir().expect("tmp");
    // The calibration drive: the reference at the axle.
    let fit = d.path().join("fit.csv");
    let sim =
        simulate(&SimOptions { length_km: 3.0, noise: "off".parse().expect("the off preset"), ..SimOptions::paper(5) })
            .expect("simulate");
    sim.drive.write_csv(&fit).expect("write");
    // The validation drive: the reference 0.9 m behind and 0.3 m left of the axle, turned by −10 mrad.
    let mount = Extrinsics { lever_x: -0.9, lever_y: 0.3, heading_offset: -0.01 };
    let other = simulate(&SimOptions {
        length_km: 3.0,
        reference_mount: mount,
        noise: "off".parse().expect("the off preset"),
        ..SimOptions::paper(6)
    })
    .expect("simulate");
    let csv = d.path().join("other.csv");
    other.drive.write_csv(&csv).expect("write");
    let toml = d.path().join("other.toml");
    let reference = "\n[reference]\nlever_arm = [-0.9, 0.3]\nheading_offset = -0.01\n";
    std::fs::write(&toml, canonical_manifest("other.csv", reference)).expect("write");
    let bare = d.path().join("bare.toml");
    std::fs::write(&bare, canonical_manifest("other.csv", "")).expect("write");

    // Without its [reference] (CSV, or a manifest without one): the reference taken for the axle.
    let without = calibrate(&fit, &["--validate-on", csv.to_str().expect("utf8")]);
    let row = &without["validate_on"]["drives"][0];
    assert!(row["extrinsics"].is_null(), "{row}");
    let without = calibrate(&fit, &["--validate-on", bare.to_str().expect("utf8")]);
    let row = &without["validate_on"]["drives"][0];
    assert!(row["extrinsics"].is_null(), "{row}");
    let e_without = row["mean_position_error_m"].as_f64().expect("Ē_p");

    // With it: the drive's own values, said so; the calibration (and θ) is the same.
    let with = calibrate(&fit, &["--validate-on", toml.to_str().expect("utf8")]);
    assert_eq!(with["theta"], without["theta"]);
    let row = &with["validate_on"]["drives"][0];
    let x = &row["extrinsics"];
    assert_eq!(x["value"]["lever_x"], -0.9, "{x}");
    assert_eq!(x["value"]["heading_offset"], -0.01, "{x}");
    assert_eq!(x["source"]["lever_x"], "drive", "{x}");
    assert_eq!(x["source"]["heading_offset"], "drive", "{x}");
    assert!(x["conflicts"].is_null(), "{x}");
    let e_with = row["mean_position_error_m"].as_f64().expect("Ē_p");
    eprintln!("Ē_p on the validation drive: {e_with} m with its [reference], {e_without} m without");
    assert!(e_with < 0.5 * e_without, "Ē_p with the drive's extrinsics {e_with} m, without {e_without} m");
    // The report's own held-out Ē_p (the verdict's) uses them too.
    let held = |r: &serde_json::Value| r["validation"]["mean_position_error_m"].as_f64().expect("Ē_p");
    assert!((held(&with) - e_with).abs() < 1e-9 * e_with, "one drive: the same segments");
    assert!(held(&with) < held(&without));

    // `odocal validate` on the manifest applies its [reference] too, held
    // as batch G-N held it: the same Ē_p.
    let t = &with["theta"];
    let theta = format!("{},{},{},{}", t["c_e"], t["c_d"], t["t_r"], t["d"]);
    let args = ["validate", toml.to_str().expect("utf8"), "--theta", &theta, "--carry-heading-offset"];
    let o = odocal(&[&args[..], &["--json", "-"]].concat());
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(v["extrinsics"]["lever_x"], -0.9, "{v}");
    let e = v["mean_position_error_m"].as_f64().expect("Ē_p");
    assert!((e - e_with).abs() < 1e-9 * e_with, "validate {e} m, validate-on {e_with} m");
    // Without the flag, the typed θ's drive re-estimates its heading offset
    // from the manifest's −10 mrad, the lever arm kept.
    let o = odocal(&args[..4]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    assert!(out.contains("(the drive's manifest states -10.0; --carry-heading-offset holds that)"), "{out}");
    assert!(out.contains("heading_offset re-estimated on this drive, the rest from the drive's manifest [reference]"));
    // Its reachable-minimum search takes the same mount, so it is never above Ē_p of θ.
    let args = ["validate", toml.to_str().expect("utf8"), "--theta", &theta, "--reachable-minimum"];
    let o = odocal(&[&args[..], &["--json", "-"]].concat());
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(v["reachable_minimum"]["extrinsics"], v["extrinsics"], "{v}");
    assert!(v["reachable_minimum"]["mean_position_error_m"].as_f64().expect("minimum") <= e, "{v}");
    let bare = bare.to_str().expect("utf8");
    let o = odocal(&["validate", bare, "--theta", &theta, "--carry-heading-offset", "--json", "-"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert!(v["extrinsics"].is_null(), "{v}");
    assert!((v["mean_position_error_m"].as_f64().expect("Ē_p") - e_without).abs() < 1e-9 * e_without);

    // A command-line lever arm wins for every drive: reported as a conflict.
    let fit_s = fit.to_str().expect("utf8");
    let o = odocal(&[
        "calibrate",
        fit_s,
        "--method",
        "batch-gn",
        "--lever-arm",
        "0,0",
        "--validate-on",
        toml.to_str().expect("utf8"),
    ]);
    assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    assert!(out.contains("reference extrinsics: lever arm (+0.000, +0.000) m [the command line], heading offset -10.00 mrad [the drive's manifest]"), "{out}");
    assert!(
        out.contains("CONFLICT: its manifest states lever_x = -0.900 m, +0.000 m (the command line) was used"),
        "{out}"
    );
}
