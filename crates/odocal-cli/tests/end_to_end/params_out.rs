//! `--params-out` (YAML and JSON), the JSON report's `sigma` and the
//! terminal report give one σ for one run: the one that stands for the
//! result (the verdict's) — the 3-step's batch spread, batch-gn's
//! cluster-robust σ — not the model σ (step 3's covered 0 % of 3-step
//! errors in the coverage study).

use crate::common;

use common::{odocal, stderr, stdout};
use serde_json::Value;

/// `c_e_sigma: 1.23e-3` and friends of a ROS 2 parameter file, read back.
fn yaml_number(yaml: &str, key: &str) -> Option<f64> {
    let prefix = format!("{key}: ");
    yaml.lines().find_map(|l| l.trim().strip_prefix(prefix.as_str())).map(|v| {
        let v = v.split_whitespace().next().expect("value");
        v.parse().unwrap_or_else(|e| panic!("{key}: {v}: {e}"))
    })
}

fn sqrt_diag(c: &Value, i: usize) -> f64 {
    c[i][i].as_f64().expect("covariance entry").sqrt()
}

#[test]
fn params_file_json_and_text_give_the_result_sigma() {
    let d = tempfile::tempdir().expect("tmp");
    // 3 km for the 3-step (a few seconds in the test profile); 5 km for
    // batch-gn, the shortest with the 10 clusters its robust σ needs.
    let short = common::simulated_drive(d.path(), "drive3.csv", &["--seed", "1", "--length-km", "3"]);
    let long = common::simulated_drive(d.path(), "drive5.csv", &["--seed", "1", "--length-km", "5"]);
    let dstr = short.as_str();

    // The 3-step: the batch-spread σ everywhere.
    let (yaml, json) = (d.path().join("p.yaml"), d.path().join("r.json"));
    let o = odocal(&[
        "calibrate",
        dstr,
        "--method",
        "three-step",
        "--batches",
        "8",
        "--picks",
        "3",
        "--params-out",
        yaml.to_str().expect("utf8"),
        "--json",
        json.to_str().expect("utf8"),
    ]);
    assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", stderr(&o));
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    let y = std::fs::read_to_string(&yaml).expect("yaml");
    let out = stdout(&o);
    assert_eq!(r["sigma"]["source"], "batch-spread", "{}", r["sigma"]);
    assert!(y.contains("sigma: \"batch-spread\""), "{y}");
    assert_eq!(r["sigma"]["covers"], "next-drive", "{}", r["sigma"]);
    assert_eq!(r["sigma_within_drive"]["covers"], "within-drive", "{}", r["sigma_within_drive"]);
    assert!(y.contains("sigma_covers: \"σ for the next drive: within-drive ⊕ between-drive\""), "{y}");
    assert!(
        out.contains(
            "σ of the result (verdict, --params-out, --report, JSON `sigma`): ± 1σ (next drive) = σ for the next \
             drive: within-drive ⊕ between-drive"
        ),
        "{out}"
    );
    assert!(out.contains("within-drive ± 1σ (spread, JSON `sigma_within_drive`)"), "{out}");
    let spread = &r["uncertainty"]["batch_spread"]["covariance"];
    let between = &r["next_drive_sigma"]["between_drive"];
    for (i, name) in ["c_e", "c_d", "t_r", "d"].into_iter().enumerate() {
        let s = sqrt_diag(spread, i);
        let file = yaml_number(&y, &format!("{name}_sigma")).expect("sigma in the file");
        let b = between[i].as_f64().expect("between-drive σ");
        let next = (s * s + b * b).sqrt();
        assert!((file - next).abs() <= 1e-12 * next, "{name}: file {file} vs batch spread ⊕ prior {next}");
        assert_eq!(r["sigma"][name].as_f64(), Some(file), "{name}");
        assert_eq!(r["sigma_within_drive"][name].as_f64(), Some(s), "{name}");
        let model = sqrt_diag(&r["covariance"], i);
        assert!(s > 10.0 * model, "{name}: the model σ {model} is what the file must not hold (spread {s})");
    }
    // The text's c_e row holds the same σ (6 decimals, as printed).
    let c_e = sqrt_diag(spread, 0);
    let row = out.lines().find(|l| l.trim_start().starts_with("c_e")).expect("c_e row");
    assert!(row.contains(&format!("{c_e:.6}")), "{row} lacks {c_e:.6}");

    // batch-gn: its cluster-robust σ; a held parameter is held in both.
    let params = d.path().join("p.json");
    let o = odocal(&[
        "calibrate",
        long.as_str(),
        "--method",
        "batch-gn",
        "--fix",
        "d",
        "--params-out",
        params.to_str().expect("utf8"),
        "--json",
        json.to_str().expect("utf8"),
    ]);
    assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", stderr(&o));
    let r: Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    let p: Value = serde_json::from_str(&std::fs::read_to_string(&params).expect("params")).expect("params");
    assert_eq!(r["sigma"]["source"], "cluster-robust", "{}", r["sigma"]);
    assert_eq!(p["provenance"]["sigma"], "cluster-robust", "{p}");
    let robust = &r["identification"]["robust"]["covariance"];
    for (i, name) in ["c_e", "c_d", "t_r"].into_iter().enumerate() {
        let s = sqrt_diag(robust, i);
        let b = r["next_drive_sigma"]["between_drive"][i].as_f64().expect("between-drive σ");
        let file = p["parameters"][format!("{name}_sigma")].as_f64().expect("σ");
        assert!((file - (s * s + b * b).sqrt()).abs() <= 1e-12 * file, "{name}: {p}");
        assert_eq!(r["sigma"][name].as_f64(), Some(file), "{name}");
        assert_eq!(r["sigma_within_drive"][name].as_f64(), Some(s), "{name}");
    }
    assert_eq!(p["parameters"]["d_held"], true, "{p}");
    assert!(r["sigma"]["d"].is_null(), "{}", r["sigma"]);
    assert!(stdout(&o).contains("± 1σ (robust)"), "{}", stdout(&o));
}

/// A parameter file `--params-out` wrote is a θ for `validate --theta` (and
/// `--theta0`): read back to the bit, with the heading offset it estimated
/// (the default method, EIV, estimates it with its batch G-N start)
/// carried, it gives the calibration's own Ē_p exactly; the bare numbers,
/// without the offset, do not. On this drive, the calibration's own,
/// `validate` holds that offset by default too (it re-estimates one on
/// other drives).
#[test]
fn a_params_file_validates_like_the_calibration_that_wrote_it() {
    let d = tempfile::tempdir().expect("tmp");
    let drive = common::simulated_drive(d.path(), "drive.csv", &["--seed", "2", "--length-km", "5"]);
    let dstr = drive.as_str();
    let (yaml, pjson, json) = (d.path().join("p.yaml"), d.path().join("p.json"), d.path().join("c.json"));
    let path = |p: &std::path::Path| p.to_str().expect("utf8").to_string();
    for params in [&yaml, &pjson] {
        let o = odocal(&["calibrate", dstr, "--params-out", &path(params), "--json", &path(&json)]);
        assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", stderr(&o));
    }
    let c: Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    let own = c["validation"]["mean_position_error_m"].as_f64().expect("Ē_p");
    let offset = c["extrinsics"]["value"]["heading_offset"].as_f64().expect("heading offset");
    assert!(offset.abs() > 1e-4, "the simulated reference has a heading offset to estimate: {offset}");
    let validate = |theta: &str, extra: &[&str]| -> Value {
        let o = odocal(&[&["validate", dstr, "--theta", theta, "--json", "-"], extra].concat());
        assert!(o.status.success(), "{}", stderr(&o));
        serde_json::from_str(&stdout(&o)).expect("json")
    };
    let ep = |theta: &str| validate(theta, &["--carry-heading-offset"])["mean_position_error_m"].as_f64().expect("Ē_p");
    assert_eq!(ep(&path(&yaml)).to_bits(), own.to_bits());
    assert_eq!(ep(&path(&pjson)).to_bits(), own.to_bits());
    for params in [&yaml, &pjson] {
        let held = validate(&path(params), &[]);
        assert_eq!(held["calibration_drive"], serde_json::json!(true), "{held}");
        assert!(held["heading_offset_fit"].is_null(), "{held}");
        assert_eq!(held["extrinsics"]["heading_offset"].as_f64().map(f64::to_bits), Some(offset.to_bits()));
        assert_eq!(held["mean_position_error_m"].as_f64().map(f64::to_bits), Some(own.to_bits()), "{held}");
    }
    let t = &c["theta"];
    let numbers = ["c_e", "c_d", "t_r", "d"].map(|k| format!("{:?}", t[k].as_f64().expect("θ"))).join(",");
    assert_ne!(ep(&numbers).to_bits(), own.to_bits(), "without the heading offset Ē_p differs");
    let o = odocal(&["validate", dstr, "--theta", &path(&yaml)]);
    assert!(stdout(&o).contains("(from ") && stdout(&o).contains("p.yaml"), "{}", stdout(&o));
    // A file that is not one: exit 2 (a bad command line), naming it.
    let bad = d.path().join("bad.yaml");
    std::fs::write(&bad, "odocal:\n  ros__parameters:\n    c_e: 1.95\n").expect("write");
    let o = odocal(&["validate", dstr, "--theta", &path(&bad)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("bad.yaml") && stderr(&o).contains("no `c_d`"), "{}", stderr(&o));
}
