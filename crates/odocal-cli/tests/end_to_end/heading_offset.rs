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
    let mount = Extrinsics { heading_offset: delta, ..Extrinsics::default() };
    let s = simulate(&SimOptions {
        length_km: 3.0,
        substeps: 1,
        reference_mount: mount,
        noise: "off".parse().expect("the off preset"),
        ..SimOptions::paper(seed)
    })
    .expect("simulate");
    let p = dir.join(name);
    s.drive.write_csv(&p).expect("write");
    p.to_str().expect("utf8").to_owned()
}

/// `validate ARGS` as JSON and as text, each exiting with `code` (3: θ
/// does not fit the drive).
fn validate_exiting(code: i32, args: &[&str]) -> (serde_json::Value, String) {
    let mut all = vec!["validate"];
    all.extend_from_slice(args);
    let json = odocal(&[all.as_slice(), &["--json", "-"]].concat());
    assert_eq!(json.status.code(), Some(code), "{}", stderr(&json));
    let text = odocal(&all);
    assert_eq!(text.status.code(), Some(code), "{}", stderr(&text));
    (serde_json::from_slice(&json.stdout).expect("json"), stdout(&text))
}

fn validate(args: &[&str]) -> (serde_json::Value, String) {
    validate_exiting(0, args)
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
    // The line of the extrinsics in force says where the re-estimated δ comes from, not the file.
    let line = text.lines().find(|l| l.starts_with("reference extrinsics:")).expect("extrinsics line");
    assert!(
        line.ends_with(&format!("(lever_x, lever_y from {p}, heading_offset re-estimated on this drive)")),
        "{text}"
    );

    // The library, as docs/guide.md ("The Rust library") and the example
    // `param_file` use it, judges the file as the CLI does.
    let file = odocal::ParamFile::read(&params, None).expect("read");
    let theta = odocal::Theta::try_from(&file).expect("θ");
    let mut vopts = odocal::ValidateOptions::default();
    vopts.set_extrinsics(Some(&file), None, false);
    let (other_drive, _) = odocal::load_drive(Path::new(&other)).expect("load");
    let lib = odocal::validate(&other_drive, &theta, &vopts, None).expect("validate");
    assert_eq!(lib.validation.mean_position_error_m.to_bits(), own.to_bits());
    assert_eq!(lib.extrinsics.heading_offset.to_bits(), fit_d.to_bits());

    // Carried: the calibration's δ, which tilts every path of this drive;
    // θ with it does not fit the drive, whose own fit (θ free, δ carried)
    // bends θ to make up for part of the tilt.
    let (v, text) = validate_exiting(3, &[&other, "--theta", p, "--carry-heading-offset"]);
    assert_eq!(v["drive_fit"]["fits"], serde_json::json!(false), "{v}");
    assert!(v["heading_offset_fit"].is_null(), "{v}");
    assert_eq!(v["extrinsics"]["heading_offset"].as_f64(), Some(delta));
    let carried = v["mean_position_error_m"].as_f64().expect("Ē_p");
    assert!(carried > 0.1, "Ē_p with the calibration's δ: {carried} m");
    assert!(!text.contains("re-estimated"), "{text}");
    assert!(text.contains(&format!("heading offset = 18.8000 mrad ({p})")), "{text}");

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

/// On a drive the parameter file's calibration ran on (the same drive
/// fingerprint), `validate` holds the calibration's own heading offset for
/// it instead of re-estimating one with θ held, so its Ē_p is the
/// calibration's own validation, to the bit; a joint calibration's file
/// gives each of its drives its own offset.
#[test]
fn validation_on_a_calibration_drive_holds_the_calibration_s_heading_offset() {
    let d = tempfile::tempdir().expect("tmp");
    // A noisy drive, calibrated by default: θ and δ are fitted together,
    // and δ re-estimated with θ held would differ.
    let noisy = common::simulated_drive(d.path(), "noisy.csv", &["--seed", "3", "--length-km", "4"]);
    let params = d.path().join("p.yaml");
    let p = params.to_str().expect("utf8");
    let cal = calibrate_json(Path::new(&noisy), &["--params-out", p]);
    let delta = cal["extrinsics"]["value"]["heading_offset"].as_f64().expect("δ");
    let own = cal["validation"]["mean_position_error_m"].as_f64().expect("Ē_p");
    let (v, text) = validate(&[&noisy, "--theta", p]);
    assert_eq!(v["calibration_drive"], serde_json::json!(true), "{v}");
    assert!(v["heading_offset_fit"].is_null(), "{v}");
    assert_eq!(v["extrinsics"]["heading_offset"].as_f64().map(f64::to_bits), Some(delta.to_bits()));
    assert_eq!(v["mean_position_error_m"].as_f64().map(f64::to_bits), Some(own.to_bits()), "{v}");
    let line = format!("heading offset held at {:.1} mrad, the calibration's own estimate for this drive", delta * 1e3);
    assert!(text.contains(&line) && !text.contains("re-estimated"), "{text}");
    // Without the file's drives, the offset is re-estimated, and differs.
    let file = odocal::ParamFile::read(&params, None).expect("read");
    let theta = odocal::Theta::try_from(&file).expect("θ");
    let mut vopts = odocal::ValidateOptions::default();
    vopts.set_extrinsics(Some(&file), None, false);
    assert_eq!(vopts.calibration_heading_offsets.len(), 1);
    let (loaded, _) = odocal::load_drive(Path::new(&noisy)).expect("load");
    vopts.calibration_heading_offsets.clear();
    let refit = odocal::validate(&loaded, &theta, &vopts, None).expect("validate");
    let refit_delta = refit.heading_offset_fit.expect("re-estimated").value;
    assert!((refit_delta - delta).abs() > 1e-6, "re-estimated {refit_delta} against the calibration's {delta}");
    assert!(!refit.calibration_drive);

    // A joint calibration: each drive its own offset, not the mean.
    let a = drive(d.path(), "a.csv", 33, 0.0188);
    let b = drive(d.path(), "b.csv", 34, 0.0142);
    let joint = d.path().join("joint.yaml");
    let j = joint.to_str().expect("utf8");
    let args = ["--method", "batch-gn", "--estimate", "heading-offset", "--max-iterations", "30", "--params-out", j];
    let o = odocal(&[["calibrate", &a, &b, "--json", "-"].as_slice(), &args].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let cal: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let per = cal["heading_offset_per_drive"].as_array().expect("per drive");
    for (path, row) in [&a, &b].into_iter().zip(per) {
        let (v, _) = validate(&[path, "--theta", j]);
        assert_eq!(v["calibration_drive"], serde_json::json!(true), "{path}: {v}");
        let want = row["value"].as_f64().expect("δ");
        assert_eq!(v["extrinsics"]["heading_offset"].as_f64().map(f64::to_bits), Some(want.to_bits()), "{path}");
    }
    // Another drive: re-estimated as before.
    let (v, _) = validate(&[&noisy, "--theta", j]);
    assert!(v["calibration_drive"].is_null() && !v["heading_offset_fit"].is_null(), "{v}");
}

/// The text between `start` and the next `end` after it in `s`.
fn between<'a>(s: &'a str, start: &str, end: &str) -> &'a str {
    let i = s.find(start).unwrap_or_else(|| panic!("no {start:?} in the page")) + start.len();
    let j = s[i..].find(end).expect("end") + i;
    &s[i..j]
}

/// The HTML report of a calibration with estimated extrinsics (the default
/// method estimates the heading offset; the simulated reference has one)
/// shows the JSON's Ē_p of θ_0 and of θ, and its σ, for θ and the extrinsics.
#[test]
fn the_html_report_shows_the_json_s_mean_position_error_and_sigma() {
    let d = tempfile::tempdir().expect("tmp");
    let drive = common::simulated_drive(d.path(), "drive.csv", &["--seed", "2", "--length-km", "5"]);
    let (json, html) = (d.path().join("c.json"), d.path().join("r.html"));
    let path = |p: &Path| p.to_str().expect("utf8").to_owned();
    let o = odocal(&["calibrate", &drive, "--json", &path(&json), "--report", &path(&html)]);
    assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    let page = std::fs::read_to_string(&html).expect("html");
    let x = &r["extrinsics"];
    assert!(x["value"]["heading_offset"].as_f64().expect("δ").abs() > 1e-4, "{x}");
    let ep = |v: &serde_json::Value| format!("{:.3}", v["mean_position_error_m"].as_f64().expect("Ē_p"));
    assert_eq!(between(&page, "<tr><td>calibrated</td><td><b>", "</b>"), ep(&r["validation"]));
    assert_eq!(between(&page, "<tr><td>θ_0 (initial)</td><td>", "</td>"), ep(&r["initial"]));
    // σ: the fifth cell of each parameter's row.
    let sigma_cell = |name: &str| -> String {
        let row = between(&page, &format!("<tr><td>{name}</td>"), "</tr>");
        row.split("<td>").nth(4).expect("σ cell").trim_end_matches("</td>").to_owned()
    };
    for (name, scale) in [("c_e", 1.0), ("c_d", 1e3), ("t_r", 1.0), ("d", 1e3)] {
        let want = r["sigma"][name].as_f64().map_or("held".to_owned(), |s| format!("{:.6}", s * scale));
        assert_eq!(sigma_cell(name), want, "{name}");
    }
    let robust = x["robust"]["std_dev"]["heading_offset"].as_f64();
    let delta_sd = robust.or(x["std_dev"]["heading_offset"].as_f64()).expect("σ of δ");
    assert_eq!(sigma_cell("heading_offset"), format!("{:.6}", delta_sd * 1e3));
    // θ's σ is the σ for the next drive; the extrinsics' is labelled with its own kind, as in the text.
    let table = between(&page, "<section id=\"parameters\">", "</table>");
    let kind = if robust.is_some() { "± 1σ (robust)" } else { "± 1σ (model)" };
    let (theta_rows, extrinsics_rows) = table.split_at(table.find("<tr><td>lever_x</td>").expect("lever_x row"));
    assert!(theta_rows.contains("<th>± 1σ (next drive)</th>"), "{table}");
    assert!(theta_rows.ends_with(&format!("<th>{kind}</th></tr>\n")), "{table}");
    assert!(!extrinsics_rows.contains("next drive"), "{table}");
}

/// Two drives calibrated jointly: one θ, each drive's own δ (JSON
/// `heading_offset_per_drive` with the drives' paths and fingerprints, the
/// text's list, the parameter file's provenance), their mean as the
/// carried value.
#[test]
fn a_joint_calibration_fits_each_drive_s_heading_offset() {
    let d = tempfile::tempdir().expect("tmp");
    let a = drive(d.path(), "a.csv", 33, 0.0188);
    let b = drive(d.path(), "b.csv", 34, 0.0142);
    let params = d.path().join("p.yaml");
    let p = params.to_str().expect("utf8");
    let args = ["calibrate", &a, &b, "--method", "batch-gn", "--estimate", "heading-offset", "--max-iterations", "30"];
    let html = d.path().join("r.html");
    let h = html.to_str().expect("utf8");
    let o = odocal(&[args.as_slice(), &["--json", "-", "--params-out", p, "--report", h]].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let per = v["heading_offset_per_drive"].as_array().expect("heading_offset_per_drive");
    assert_eq!(per.len(), 2, "{per:?}");
    for (row, (path, want)) in per.iter().zip([(&a, 0.0188), (&b, 0.0142)]) {
        let got = row["value"].as_f64().expect("value");
        assert!((got - want).abs() < 1e-9, "{path}: δ {got} vs {want}");
        assert_eq!(row["source"].as_str(), Some(path.as_str()));
        assert!(row["sigma"].as_f64().is_some_and(|s| s >= 0.0), "{row}");
        let fp = v["drives"].as_array().expect("drives").iter().find(|e| e["path"] == path.as_str()).expect("entry");
        assert_eq!(row["fingerprint"], fp["fingerprint"]);
    }
    let mean = v["extrinsics"]["value"]["heading_offset"].as_f64().expect("δ");
    assert!((mean - 0.5 * (0.0188 + 0.0142)).abs() < 1e-9, "carried δ {mean}");
    assert!(v["validation"]["mean_position_error_m"].as_f64().expect("Ē_p") < 1e-6, "{}", v["validation"]);
    let yaml = std::fs::read_to_string(&params).expect("params");
    // Each drive's offset in full (shortest round-trip form).
    let per_line = yaml.lines().find_map(|l| l.trim().strip_prefix("heading_offset_per_drive: \"")).expect("per drive");
    for (k, entry) in per_line.trim_end_matches('"').split("; ").enumerate() {
        let value = entry.strip_prefix(&format!("drive {}: ", k + 1)).and_then(|e| e.split(" ± ").next());
        let want = per[k]["value"].as_f64().expect("δ");
        assert_eq!(value.and_then(|x| x.parse::<f64>().ok()).map(f64::to_bits), Some(want.to_bits()), "{yaml}");
    }
    let text = stdout(&odocal(&args));
    assert!(text.contains("heading offset per drive") && text.contains("drive 2: δ = 14.2000 mrad"), "{text}");
    // The HTML report lists them too, under their mean.
    let page = std::fs::read_to_string(&html).expect("html");
    for (k, want) in [(1, "18.800000"), (2, "14.200000")] {
        let row = between(&page, &format!("<tr><td>heading_offset, drive {k}</td>"), "</tr>");
        assert!(row.contains(&format!("<b>{want}</b>")), "drive {k}: {row}");
    }
    let mean = between(&page, "<tr><td>heading_offset</td>", "</tr>");
    assert!(mean.contains("<b>16.500000</b>"), "{mean}");
}

/// The compensated wheel rotations (`n_rl_comp`, then `n_rr_comp`) of
/// `compensate DRIVE --theta THETA ARGS… --out OUT`, and what it printed.
fn compensated(drive: &str, theta: &str, args: &[&str], out: &Path) -> (Vec<f64>, String) {
    let o = odocal(&[&["compensate", drive, "--theta", theta, "--out", out.to_str().expect("utf8")], args].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(out).expect("csv");
    let mut lines = csv.lines().filter(|l| !l.starts_with('#'));
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect("column");
    let (rl, rr) = (col("n_rl_comp"), col("n_rr_comp"));
    let rows: Vec<Vec<f64>> = lines.map(|l| l.split(',').map(|c| c.parse().unwrap_or(f64::NAN)).collect()).collect();
    let values = rows.iter().map(|r| r[rl]).chain(rows.iter().map(|r| r[rr])).collect();
    (values, stdout(&o))
}

/// Largest absolute difference.
fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

/// `compensate --theta FILE` applies the file's reference extrinsics as
/// `validate` does: on a drive whose reference is turned by 18.8 mrad, the
/// file's heading offset (carried, or held as the calibration's own on
/// its own drive) gives the wheels compensated on the same drive recorded at the axle; so does
/// the bare θ, whose drive's heading offset is re-estimated from 0, and
/// with it held at 0 it does not.
#[test]
fn compensation_applies_the_parameter_file_s_extrinsics() {
    let d = tempfile::tempdir().expect("tmp");
    let turned = drive(d.path(), "turned.csv", 35, 0.0188);
    let axle = drive(d.path(), "axle.csv", 35, 0.0);
    let params = d.path().join("p.yaml");
    let p = params.to_str().expect("utf8");
    let cal = calibrate_json(
        Path::new(&turned),
        &["--method", "batch-gn", "--estimate", "heading-offset", "--max-iterations", "30", "--params-out", p],
    );
    let t = &cal["theta"];
    let theta = ["c_e", "c_d", "t_r", "d"].map(|n| t[n].as_f64().expect("θ").to_string()).join(",");
    let out = d.path().join("out.csv");
    let (at_axle, _) = compensated(&axle, &theta, &[], &out);
    let (bare, text) = compensated(&turned, &theta, &["--carry-heading-offset"], &out);
    assert!(!text.contains("reference extrinsics"), "{text}");
    let (bare_refitted, text) = compensated(&turned, &theta, &[], &out);
    assert!(text.contains("heading offset re-estimated on this drive: 18.8 mrad (from 0: neither"), "{text}");
    let (carried, text) = compensated(&turned, p, &["--carry-heading-offset"], &out);
    assert!(text.contains(&format!("heading offset = 18.8000 mrad ({p})")), "{text}");
    // The file's own drive: its calibration's offset for it, held.
    let (refitted, text) = compensated(&turned, p, &[], &out);
    assert!(text.contains("heading offset held at 18.8 mrad, the calibration's own estimate for this drive"), "{text}");
    let off = max_diff(&bare, &at_axle);
    assert!(off > 1e-3, "the bare θ on the turned drive: {off} rev/s from the axle's");
    for (name, got) in
        [("carried", &carried), ("its own drive's, held", &refitted), ("bare, re-estimated", &bare_refitted)]
    {
        let diff = max_diff(got, &at_axle);
        // Equal to round-off (2e-14 and 7e-14 rev/s measured; the bare θ 0.032).
        assert!(diff < 1e-9, "{name}: {diff} rev/s from the axle's (bare θ: {off})");
    }
}

/// The truth's row dead-reckons with the true θ and the reference's true
/// heading offset as the data show it: the mount's plus the reference's
/// constant heading bias (a random noise world's `heading_bias_rad`). On
/// a drive whose only error is that bias the truth's Ē_p is round-off, as
/// the calibration's is with its estimated δ.
#[test]
fn the_truth_row_carries_the_reference_s_heading_bias() {
    let d = tempfile::tempdir().expect("tmp");
    let off: odocal::sim::NoiseOptions = "off".parse().expect("preset");
    let noise = odocal::sim::NoiseOptions { heading_bias_rad: 0.02, ..off };
    let s = simulate(&SimOptions { length_km: 3.0, substeps: 1, noise, ..SimOptions::paper(33) }).expect("simulate");
    let p = d.path().join("biased.csv");
    s.drive.write_csv(&p).expect("write");
    s.sidecar.write_beside(&p).expect("sidecar");
    let v = calibrate_json(&p, &["--method", "batch-gn", "--estimate", "heading-offset", "--max-iterations", "30"]);
    let truth = v["truth"]["mean_position_error_m"].as_f64().expect("truth Ē_p");
    let own = v["validation"]["mean_position_error_m"].as_f64().expect("Ē_p");
    assert!(truth < 1e-6 && own < 1e-6, "truth {truth} m, calibrated {own} m");
}
