//! The HTML report says which data its Ē_p, map and residuals come from, as
//! the text report heads them: the calibrated drive itself, its held-out
//! half, or the `--validate-on` drives (each with its Ē_p).

use crate::common::{odocal, simulated_drive, stderr};

/// The validation section of `calibrate ARGS… --report PAGE`.
fn validation_section(args: &[&str], page: &std::path::Path) -> String {
    let mut all = vec!["calibrate", "--method", "batch-gn", "--report", page.to_str().expect("utf8")];
    all.extend_from_slice(args);
    let o = odocal(&all);
    assert!(o.status.success(), "{}", stderr(&o));
    let html = std::fs::read_to_string(page).expect("page");
    let start = html.find("<section id=\"validation\">").expect("validation section");
    let end = html[start..].find("</section>").expect("section end") + start;
    html[start..end].to_string()
}

#[test]
fn the_page_says_what_its_validation_data_is() {
    let dir = tempfile::tempdir().expect("tmp");
    let a = simulated_drive(dir.path(), "a.csv", &["--length-km", "2", "--seed", "1"]);
    let b = simulated_drive(dir.path(), "b.csv", &["--length-km", "2", "--seed", "2"]);
    let page = dir.path().join("r.html");
    let own = validation_section(&[&a], &page);
    assert!(own.contains("The calibrated drive itself: Ē_p there flatters the fit"), "{own}");
    let half = validation_section(&[&a, "--holdout", "second-half"], &page);
    assert!(half.contains("Held-out data, not used for calibration: the half of the drive held out"), "{half}");
    let other = validation_section(&[&a, "--validate-on", &b], &page);
    assert!(other.contains("Held-out data, not used for calibration: 1 other drive(s)"), "{other}");
    assert!(other.contains(&format!("<li>{b}: ")) && other.contains(" segments)</li>"), "{other}");
}

/// The Ē_p of each row of the page's validation table (θ_0, calibrated,
/// truth), as shown.
fn shown_errors(section: &str) -> Vec<(String, String)> {
    section
        .lines()
        .filter_map(|l| {
            let cells: Vec<&str> = l.strip_prefix("<tr><td>")?.split("</td><td>").collect();
            let value = cells.get(1)?.trim_start_matches("<b>").trim_end_matches("</b>");
            Some((cells[0].to_string(), value.to_string()))
        })
        .collect()
}

/// Every Ē_p the page shows is the JSON's (and the text's) for its row,
/// after a calibration that estimated the reference's heading offset: θ_0
/// with the extrinsics the calibration started from, the calibrated θ with
/// the estimate, the truth with the true mount (on a drive simulated with
/// the reference turned by 18.8 mrad, and on one at the axle; and with
/// θ_0 equal to the truth, the two rows alike).
#[test]
fn every_mean_position_error_on_the_page_is_the_json_s() {
    let dir = tempfile::tempdir().expect("tmp");
    let plain = simulated_drive(dir.path(), "plain.csv", &["--length-km", "3", "--seed", "1"]);
    let mount = odocal::Extrinsics { heading_offset: 0.0188, ..Default::default() };
    let sim = odocal::sim::simulate(&odocal::sim::SimOptions {
        length_km: 3.0,
        reference_mount: mount,
        ..odocal::sim::SimOptions::paper(4)
    })
    .expect("simulate");
    let mounted = dir.path().join("mounted.csv");
    sim.drive.write_csv(&mounted).expect("csv");
    sim.sidecar.write_beside(&mounted).expect("sidecar");
    let mounted = mounted.to_str().expect("utf8").to_owned();
    let truth = "1.95,-0.002,1.53,0.0008";
    let (page, json) = (dir.path().join("r.html"), dir.path().join("r.json"));
    for args in [vec![plain.as_str()], vec![&mounted], vec![&plain, "--theta0", truth, "--holdout", "first-half"]] {
        let mut all =
            vec!["calibrate", "--report", page.to_str().expect("utf8"), "--json", json.to_str().expect("utf8")];
        all.extend_from_slice(&args);
        let o = odocal(&all);
        assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", stderr(&o));
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
        assert_eq!(v["extrinsics"]["free"], serde_json::json!(["heading_offset"]), "{args:?}: δ estimated");
        let html = std::fs::read_to_string(&page).expect("page");
        let section = html.split("<section id=\"validation\">").nth(1).expect("validation section");
        let section = section.split("</table>").next().expect("table end");
        let want = |key: &str| format!("{:.3}", v[key]["mean_position_error_m"].as_f64().expect("Ē_p"));
        let rows = [("θ_0 (initial)", want("initial")), ("calibrated", want("validation")), ("truth", want("truth"))];
        let shown = shown_errors(section);
        for (row, value) in &rows {
            assert!(shown.contains(&(row.to_string(), value.clone())), "{args:?}: {row} {value} in {shown:?}");
        }
        let text = crate::common::stdout(&o);
        for (name, value) in [("θ_0", &rows[0].1), ("calibrated", &rows[1].1), ("truth", &rows[2].1)] {
            assert!(text.lines().any(|l| l.starts_with(&format!("  {name} ")) && l.ends_with(&format!(" {value} m"))));
        }
    }
}

/// A parameter the data cannot determine is marked in the page's θ table
/// as the text report marks it: its σ "(not observable)" and the text's
/// line under the table (one test-track run: t_r and d not observable).
#[test]
fn the_page_marks_what_the_data_cannot_determine() {
    let dir = tempfile::tempdir().expect("tmp");
    let run = format!("{}/../../examples/psu-mapping-van-testtrack/run-14-45-26.toml", env!("CARGO_MANIFEST_DIR"));
    let page = dir.path().join("t.html");
    let o = odocal(&["calibrate", &run, "--report", page.to_str().expect("utf8")]);
    assert!(o.status.success(), "{}", stderr(&o));
    let text = crate::common::stdout(&o);
    let line = "NOT OBSERVABLE from these data (estimates not to be trusted): t_r, d";
    assert!(text.contains(line), "{text}");
    let html = std::fs::read_to_string(&page).expect("page");
    let table = html.split("<section id=\"parameters\">").nth(1).expect("parameters");
    let table = table.split("</section>").next().expect("section end");
    assert!(table.contains(&format!("<b>{line}</b>")), "{table}");
    let row =
        |name: &str| table.lines().find(|l| l.starts_with(&format!("<tr><td>{name}</td>"))).expect("row").to_string();
    for name in ["t_r", "d"] {
        assert!(row(name).ends_with(" (not observable)</td></tr>"), "{}", row(name));
    }
    for name in ["c_e", "c_d", "heading_offset"] {
        assert!(!row(name).contains("not observable"), "{}", row(name));
    }
}

/// Validated on two other drives (the README tour's command), the page
/// names each segment's drive and times it on that drive's own clock; the
/// residuals are drawn per drive; each drive's line gives the heading
/// offsets its θ_0 and θ rows used, as the JSON does.
#[test]
fn the_page_names_each_validation_drive_and_its_own_time() {
    let dir = tempfile::tempdir().expect("tmp");
    let e = format!("{}/../../examples/psu-mapping-van-testtrack", env!("CARGO_MANIFEST_DIR"));
    let run = |name: &str| format!("{e}/run-{name}.toml");
    let held = [run("15-28-33"), run("17-45-46")];
    let (page, json) = (dir.path().join("r.html"), dir.path().join("r.json"));
    let validate_on = held.join(",");
    let o = odocal(&[
        "calibrate",
        &run("14-45-26"),
        &run("16-47-33"),
        "--validate-on",
        &validate_on,
        "--report",
        page.to_str().expect("utf8"),
        "--json",
        json.to_str().expect("utf8"),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let html = std::fs::read_to_string(&page).expect("page");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("json");
    let section = |id: &str| -> String {
        let s = html.split(&format!("<section id=\"{id}\">")).nth(1).expect("section");
        s.split("</section>").next().expect("section end").to_string()
    };
    // The map: each segment shown by its drive, at a time within that drive.
    let map = section("map");
    assert!(map.contains("<h2>The drives</h2>"), "{map}");
    let line = map.lines().find(|l| l.starts_with("<p>Segments shown, numbered on the map")).expect("the list");
    let list = line.split("): ").nth(1).expect("entries").trim_end_matches(".</p>");
    let entries: Vec<&str> = list.split("; ").collect();
    assert_eq!(entries.len(), 4, "{line}");
    for (j, entry) in entries.iter().enumerate() {
        let (name, t) = entry
            .strip_prefix(&format!("{}: ", j + 1))
            .and_then(|x| x.strip_suffix(" s"))
            .and_then(|x| x.split_once(" at "))
            .unwrap_or_else(|| panic!("{entry}"));
        let path = held.iter().find(|p| p.ends_with(name)).unwrap_or_else(|| panic!("{name} is not a drive"));
        let (drive, _) = odocal::load_drive(std::path::Path::new(path)).expect("the drive");
        let t: f64 = t.parse().expect("a time");
        let (first, last) = (drive.t()[0], drive.t()[drive.len() - 1]);
        assert!(first - 0.05 <= t && t <= last, "{entry}: the drive runs {first} … {last} s");
    }
    // The residuals: a figure per drive, each on its own clock.
    let residuals = section("residuals");
    for name in ["run-15-28-33.toml", "run-17-45-46.toml"] {
        assert!(residuals.contains(&format!("Residuals on {name}")), "{name}");
        assert!(residuals.contains(&format!("t on {name}&apos;s clock (s)")), "{name}");
    }
    assert!(!residuals.contains("Residuals over the drive"));
    // Each drive's line: the heading offsets θ and θ_0 were judged with, the JSON's.
    let validation = section("validation");
    for (d, path) in v["validate_on"]["drives"].as_array().expect("drives").iter().zip(&held) {
        let x = &d["extrinsics"];
        assert_eq!(x["source"]["heading_offset"], "reestimated", "{d}");
        let mrad = |e: &serde_json::Value| format!("{:+.2} mrad", e["heading_offset"].as_f64().expect("δ") * 1e3);
        let item = validation.lines().find(|l| l.starts_with(&format!("<li>{path}: "))).expect("the drive's line");
        assert!(item.contains(&format!("heading offset {} [re-estimated on this drive;", mrad(&x["value"]))), "{item}");
        assert!(item.contains(&format!("θ_0&#39;s: heading offset {} [re-estimated", mrad(&x["initial"]))), "{item}");
        let e = |k: &str| format!("{:.3} m", d[k].as_f64().expect("Ē_p"));
        assert!(item.contains(&format!(": {} / {} (", e("mean_position_error_m"), e("initial_mean_position_error_m"))));
    }
    // Two means of the held-out Ē_p, each named by what weighs the same:
    // the drives' (the JSON's `mean_over_drives_m`) and the table's, over
    // the segments (`validation.mean_position_error_m`).
    let f = |x: &serde_json::Value| x.as_f64().expect("Ē_p");
    let (mean, initial) =
        (f(&v["validate_on"]["mean_over_drives_m"]), f(&v["validate_on"]["initial_mean_over_drives_m"]));
    let drives = format!("Ē_p (each drive weighs the same): {mean:.3} m / {initial:.3} m;");
    assert!(validation.contains(&drives), "{validation}");
    assert!(validation.contains("is over all their segments (each segment weighs the same)."), "{validation}");
    let ep = f(&v["validation"]["mean_position_error_m"]);
    assert!(validation.contains(&format!("{ep:.3}")), "the table's Ē_p {ep:.3}: {validation}");
    // The result fell back to batch G-N: the text's θ table shows its
    // cluster-robust σ, the JSON's `sigma_within_drive`, beside the σ for
    // the next drive, the JSON's `sigma`.
    assert_eq!(v["sigma"]["source"], "cluster-robust", "{}", v["sigma"]);
    let text = crate::common::stdout(&o);
    let header = text.lines().find(|l| l.contains("θ_0    calibrated")).expect("the θ table");
    assert!(header.contains("± 1σ (model) ± 1σ (robust) ± 1σ (next drive)  EIV (unused)"), "{header}");
    for (name, scale, digits) in [("c_e", 1.0, 6), ("c_d", 1e3, 4), ("t_r", 1.0, 6), ("d", 1e3, 4)] {
        let row = text.lines().find(|l| l.starts_with(&format!("  {name:<4} "))).expect("the row");
        let cells: Vec<&str> = row.split_whitespace().collect();
        let cell = |x: &serde_json::Value| format!("{:.digits$}", f(x) * scale);
        assert_eq!(cells[5], cell(&v["sigma_within_drive"][name]), "{name}: {row}");
        assert_eq!(cells[6], cell(&v["sigma"][name]), "{name}: {row}");
    }
}
