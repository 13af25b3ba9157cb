//! The reference's heading offset δ belongs to each drive: `validate` and
//! `calibrate --validate-on` re-estimate the validation drive's own δ with
//! θ held when the calibration estimated δ, and `--carry-heading-offset`
//! carries the calibration's instead. Noise-free simulated drives whose
//! references are turned by 18.8 and 14.2 mrad.

use crate::common;

use std::path::Path;

use common::{calibrate_json, odocal, stderr, stdout};
use odocal::sim::{simulate, SimOptions};
use odocal::Extrinsics;

/// A noise-free 3 km drive whose reference heading is turned by `delta`.
fn drive(dir: &Path, name: &str, seed: u64, delta: f64) -> String {
    let mount = Extrinsics { heading_offset: delta, ..Extrinsics::ZERO };
    let s =
        simulate(&SimOptions { length_km: 3.0, substeps: 1, reference_mount: mount, ..SimOptions::noise_free(seed) })
            .expect("simulate");
    let p = dir.join(name);
    s.drive.write_csv(&p).expect("write");
    p.to_str().expect("utf8").to_owned()
}

fn validate(args: &[&str]) -> (serde_json::Value, String) {
    let mut all = vec!["validate"];
    all.extend_from_slice(args);
    let json = odocal(&[all.as_slice(), &["--json", "-"]].concat());
    assert!(json.status.success(), "{}", stderr(&json));
    let text = odocal(&all);
    assert!(text.status.success(), "{}", stderr(&text));
    (serde_json::from_slice(&json.stdout).expect("json"), stdout(&text))
}

#[test]
fn validation_re_estimates_the_drive_s_own_heading_offset_unless_carried() {
    let d = tempfile::tempdir().expect("tmp");
    let fit = drive(d.path(), "fit.csv", 31, 0.0188);
    let other = drive(d.path(), "other.csv", 32, 0.0142);
    let params = d.path().join("p.yaml");
    let p = params.to_str().expect("utf8");
    let cal = calibrate_json(
        Path::new(&fit),
        &["--method", "batch-gn", "--estimate", "heading-offset", "--max-iterations", "30", "--params-out", p],
    );
    let delta = cal["extrinsics"]["value"]["heading_offset"].as_f64().expect("δ");
    assert!((delta - 0.0188).abs() < 1e-9, "calibration's δ {delta}");

    // Re-estimated (the default): the drive's own δ, θ exact, Ē_p at round-off.
    let (v, text) = validate(&[&other, "--theta", p]);
    let fit_d = v["heading_offset_fit"]["value"].as_f64().expect("heading_offset_fit");
    assert!((fit_d - 0.0142).abs() < 1e-9, "re-estimated δ {fit_d}");
    assert_eq!(v["heading_offset_fit"]["calibration"].as_f64(), Some(delta));
    assert_eq!(v["extrinsics"]["heading_offset"].as_f64(), Some(fit_d));
    let own = v["mean_position_error_m"].as_f64().expect("Ē_p");
    assert!(own < 1e-6, "Ē_p with the drive's own δ: {own} m");
    assert!(text.contains("heading offset re-estimated on this drive: 14.2 mrad (calibration's 18.8)"), "{text}");

    // Carried: the calibration's δ, which tilts every path of this drive.
    let (v, text) = validate(&[&other, "--theta", p, "--carry-heading-offset"]);
    assert!(v["heading_offset_fit"].is_null(), "{v}");
    assert_eq!(v["extrinsics"]["heading_offset"].as_f64(), Some(delta));
    let carried = v["mean_position_error_m"].as_f64().expect("Ē_p");
    assert!(carried > 0.1, "Ē_p with the calibration's δ: {carried} m");
    assert!(!text.contains("re-estimated"), "{text}");

    // --validate-on: the same per validation drive.
    let base = ["--method", "batch-gn", "--estimate", "heading-offset", "--max-iterations", "30"];
    let on = calibrate_json(Path::new(&fit), &[&base[..], &["--validate-on", &other]].concat());
    let row = &on["validate_on"]["drives"][0];
    assert_eq!(row["extrinsics"]["source"]["heading_offset"], "reestimated", "{row}");
    let x = row["extrinsics"]["value"]["heading_offset"].as_f64().expect("δ");
    assert!((x - 0.0142).abs() < 1e-9, "{row}");
    assert!(row["mean_position_error_m"].as_f64().expect("Ē_p") < 1e-6, "{row}");
    assert!(on["validation"]["mean_position_error_m"].as_f64().expect("Ē_p") < 1e-6, "{on}");
    let on =
        calibrate_json(Path::new(&fit), &[&base[..], &["--validate-on", &other, "--carry-heading-offset"]].concat());
    let row = &on["validate_on"]["drives"][0];
    assert_eq!(row["extrinsics"]["source"]["heading_offset"], "estimated", "{row}");
    assert!(row["mean_position_error_m"].as_f64().expect("Ē_p") > 0.1, "{row}");
    assert!(on["validation"]["mean_position_error_m"].as_f64().expect("Ē_p") > 0.1, "{on}");
}
