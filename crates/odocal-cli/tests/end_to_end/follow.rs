//! `odocal follow`, `odocal history` and `calibrate --vehicle --db`.

use serde_json::Value;

use crate::common::{odocal, simulated_drive, stderr, stdout};

fn json_file(p: &std::path::Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).expect("read json")).expect("json")
}

fn history_rows(db: &str) -> Vec<Value> {
    let o = odocal(&["history", "van", "--db", db, "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: Value = serde_json::from_str(&stdout(&o)).expect("history json");
    v["rows"].as_array().expect("rows").clone()
}

#[test]
fn follow_reports_each_drive_and_a_replay_adds_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--seed", "1", "--length-km", "4", "--noise", "off"]);
    let b = simulated_drive(dir.path(), "b.csv", &["--seed", "2", "--length-km", "4", "--noise", "off"]);
    let db = dir.path().join("h.sqlite");
    let (db_s, json) = (db.to_str().expect("utf8"), dir.path().join("f.json"));
    let params = dir.path().join("p.yaml");
    let args = |json: &std::path::Path| {
        let mut v = vec!["follow", &a, &b, "--vehicle", "van", "--db", db_s];
        v.extend(["--json", json.to_str().expect("utf8"), "--params-out", params.to_str().expect("utf8")]);
        v.into_iter().map(str::to_owned).collect::<Vec<String>>()
    };
    let first: Vec<String> = args(&json);
    let o = odocal(&first.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", stderr(&o));
    // Each drive's line gives θ once, each value with its σ.
    let text = stdout(&o);
    let lines: Vec<&str> = text.lines().filter(|l| l.contains("prequential Ē_p")).collect();
    assert_eq!(lines.len(), 2, "{text}");
    for l in lines {
        assert!(l.contains(" folded; c_e = ") && l.contains(" ± ") && l.contains(", d = "), "{l}");
        assert!(!l.contains("θ =") && !l.contains("± c_e"), "{l}");
    }
    let v = json_file(&json);
    let obj = v.as_object().expect("object");
    assert_eq!(obj.keys().collect::<Vec<_>>(), vec!["drives"]);
    let drives = v["drives"].as_array().expect("drives");
    assert_eq!(drives.len(), 2);
    for (d, src) in drives.iter().zip([&a, &b]) {
        assert_eq!(d["source"], src.as_str());
        assert_eq!(d["fingerprint"].as_str().expect("fingerprint").len(), 64);
        assert!(d["prequential_mean_position_error_m"].as_f64().expect("Ē_p") >= 0.0, "{d}");
        let updates = d["updates"].as_array().expect("updates");
        assert_eq!(updates.len(), 1);
        let decision = updates[0]["decision"].as_str().expect("decision");
        assert!(["written", "held", "flagged"].contains(&decision), "{decision}");
        assert!(!updates[0]["reasons"].as_array().expect("reasons").is_empty());
    }
    // Noise-free drives: the first drive's estimate is written (θ_0 bounds
    // no change), and the parameter file holds it.
    assert_eq!(drives[0]["updates"][0]["decision"], "written", "{}", drives[0]);
    let yaml = std::fs::read_to_string(&params).expect("params");
    assert!(yaml.contains("c_e:") && yaml.contains("online"), "{yaml}");
    // What a fleet script deploys: the update passed every gate.
    assert!(yaml.contains("    verdict: \"accepted\"\n"), "{yaml}");
    let rows = history_rows(db_s);
    assert!(!rows.is_empty());
    assert!(rows.iter().all(|r| r["method"] == "online"));
    // The history says what the parameter file says.
    assert!(rows.iter().all(|r| r["verdict"] == "accepted"), "{rows:?}");

    // The same drives again: nothing new.
    let json2 = dir.path().join("f2.json");
    let second: Vec<String> = args(&json2);
    let o = odocal(&second.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", stderr(&o));
    let v2 = json_file(&json2);
    for d in v2["drives"].as_array().expect("drives") {
        assert_eq!(d["already_recorded"], true, "{d}");
        assert_eq!(d["updates"].as_array().expect("updates").len(), 0);
    }
    assert_eq!(history_rows(db_s).len(), rows.len());
}

#[test]
fn follow_never_overwrites_an_input() {
    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--seed", "3", "--length-km", "2", "--noise", "off"]);
    let before = std::fs::read(&a).expect("drive");
    for flag in ["--db", "--json", "--params-out"] {
        let db = dir.path().join("h.sqlite");
        let db_s = db.to_str().expect("utf8");
        let mut args = vec!["follow", a.as_str(), "--vehicle", "van"];
        if flag == "--db" {
            args.extend(["--db", a.as_str()]);
        } else {
            args.extend(["--db", db_s, flag, a.as_str()]);
        }
        let o = odocal(&args);
        assert!(!o.status.success(), "{flag} onto the drive was accepted");
        assert!(stderr(&o).contains("a.csv"), "{}", stderr(&o));
        assert_eq!(std::fs::read(&a).expect("drive"), before, "{flag} changed the drive");
    }
}

#[test]
fn calibrate_records_a_drive_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--seed", "4", "--length-km", "3"]);
    let db = dir.path().join("h.sqlite");
    let db_s = db.to_str().expect("utf8");
    let run = || odocal(&["calibrate", &a, "--method", "batch-gn", "--vehicle", "van", "--db", db_s]);
    let o = run();
    assert!(o.status.code() != Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("recorded in"), "{}", stderr(&o));
    let o = run();
    assert!(stderr(&o).contains("already recorded"), "{}", stderr(&o));
    let rows = history_rows(db_s);
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0]["method"], "batch-gn");
    assert!(rows[0]["sigma"]["c_e"].as_f64().expect("σ") > 0.0, "{}", rows[0]);
    // --vehicle needs --db.
    assert!(!odocal(&["calibrate", &a, "--vehicle", "van"]).status.success());
    let o = odocal(&["history", "van", "--db", db_s]);
    assert!(o.status.success() && stdout(&o).contains("batch-gn"), "{}", stdout(&o));
    // An unknown vehicle is an error naming those the database holds.
    let o = odocal(&["history", "truck", "--db", db_s, "--json", "-"]);
    assert_eq!(o.status.code(), Some(1), "{}", stdout(&o));
    assert!(stdout(&o).is_empty(), "{}", stdout(&o));
    assert!(stderr(&o).contains("no vehicle 'truck'") && stderr(&o).contains("holds are 'van'"), "{}", stderr(&o));
    // A row --pool names that the vehicle does not have is an error naming the rows it has.
    let o = odocal(&["history", "van", "--db", db_s, "--pool", "1,7"]);
    assert_eq!(o.status.code(), Some(1), "{}", stdout(&o));
    assert!(
        stderr(&o).contains("--pool: vehicle 'van' has no row 7") && stderr(&o).contains("rows are 1"),
        "{}",
        stderr(&o)
    );
    assert!(odocal(&["history", "van", "--db", db_s, "--pool", "1"]).status.success());
}

#[test]
fn history_report_plots_each_parameter_with_the_rows() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("h.sqlite");
    let db_s = db.to_str().expect("utf8");
    for (name, seed) in [("a.csv", "5"), ("b.csv", "6")] {
        let d = simulated_drive(dir.path(), name, &["--seed", seed, "--length-km", "3"]);
        let o = odocal(&["calibrate", &d, "--method", "batch-gn", "--vehicle", "van <&>", "--db", db_s]);
        assert!(o.status.code() != Some(1), "{}", stderr(&o));
    }
    let report = dir.path().join("van.html");
    let o = odocal(&["history", "van <&>", "--db", db_s, "--report", report.to_str().expect("utf8")]);
    assert!(o.status.success(), "{}", stderr(&o));
    let html = std::fs::read_to_string(&report).expect("report written");
    assert_eq!(html.matches("<svg").count(), 4, "one plot per parameter");
    for name in ["c_e", "c_d", "t_r", "d"] {
        assert!(html.contains(&format!("<figure id=\"plot-{name}\">")), "{name}");
    }
    assert!(html.contains("van &lt;&amp;&gt;") && !html.contains("van <&>"));
    let o = odocal(&["history", "van <&>", "--db", db_s, "--json", "-"]);
    let v: Value = serde_json::from_str(&stdout(&o)).expect("history json");
    let rows = v["rows"].as_array().expect("rows");
    assert_eq!(rows.len(), 2);
    // 3 km batch G-N fits: no cluster-robust σ, the model's alone; a drift
    // flag between them says it is no evidence by itself.
    for f in v["drift"].as_array().expect("drift") {
        assert_eq!(f["model_sigma_only"], true, "{f}");
    }
    let text = stdout(&odocal(&["history", "van <&>", "--db", db_s]));
    let flags = v["drift"].as_array().expect("drift").len();
    assert_eq!(text.matches("a σ of the model alone").count(), flags, "{text}");
    for r in rows {
        assert_eq!(r["sigma_model_only"], true, "{r}");
        let c_e = r["theta"]["c_e"].as_f64().expect("c_e");
        assert!(html.contains(&format!("{c_e:.6}")), "row value {c_e} missing");
        assert!(html.contains(r["recorded_at"].as_str().expect("recorded_at")));
    }
    // A database that is not one: a clear error, no report.
    let bad = dir.path().join("bad.sqlite");
    std::fs::write(&bad, "not a database\n".repeat(100)).expect("write");
    let out = dir.path().join("bad.html");
    let o = odocal(&["history", "van", "--db", bad.to_str().expect("utf8"), "--report", out.to_str().expect("utf8")]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("bad.sqlite") && !out.exists(), "{}", stderr(&o));
}

#[test]
fn simulate_with_drift_records_it_in_the_sidecar() {
    let dir = tempfile::tempdir().expect("tempdir");
    let args = ["--seed", "7", "--length-km", "2", "--ce-ramp-per-hour", "-0.003", "--cd-step", "0.5@60"];
    let d = simulated_drive(dir.path(), "drift.csv", &args);
    let side = json_file(&std::path::Path::new(&d).with_extension("json"));
    assert_eq!(side["settings"]["drift"]["c_e_relative_per_hour"], -0.003);
    assert_eq!(side["settings"]["drift"]["c_d_step"]["at_s"], 60.0);
    let (start, end) = (&side["theta_true"], &side["theta_true_end"]);
    assert!(end["c_e"].as_f64().expect("c_e") < start["c_e"].as_f64().expect("c_e"));
    let dc_d = end["c_d"].as_f64().expect("c_d") - start["c_d"].as_f64().expect("c_d");
    assert!((dc_d - 5e-4).abs() < 1e-12, "{dc_d}");
    let plain = simulated_drive(dir.path(), "plain.csv", &["--seed", "7", "--length-km", "2"]);
    let side = std::fs::read_to_string(std::path::Path::new(&plain).with_extension("json")).expect("sidecar");
    assert!(!side.contains("theta_true_end") && !side.contains("\"drift\""));
    let o = odocal(&["simulate", "--out", dir.path().join("x.csv").to_str().expect("utf8"), "--cd-step", "0.5"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("MM@SECONDS"), "{}", stderr(&o));
}

/// A CSV drive is replayed as a stream: its fingerprint is the drive's
/// (the simulator's sidecar records it from the drive in memory), a gap
/// (`part` column) is followed, and a bad row is named as `calibrate`
/// names it.
#[test]
fn follow_streams_csv_drives_with_the_whole_readers_fingerprint_and_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--seed", "7", "--length-km", "2"]);
    let sidecar = json_file(&dir.path().join("a.json"));
    // The same drive with a gap of 4 s after its first half.
    let text = std::fs::read_to_string(&a).expect("drive");
    let rows: Vec<&str> = text.lines().collect();
    let half = rows.len() / 2;
    let mut gapped = format!("{},part\n", rows[0]);
    for (i, row) in rows.iter().enumerate().skip(1) {
        let (t, rest) = row.split_once(',').expect("row");
        let t: f64 = t.parse().expect("t");
        let (t, part) = if i < half { (t, 0) } else { (t + 4.0, 1) };
        gapped.push_str(&format!("{t},{rest},{part}\n"));
    }
    let b = dir.path().join("b.csv");
    std::fs::write(&b, gapped).expect("write");
    let db = dir.path().join("h.sqlite");
    let json = dir.path().join("f.json");
    let (b_s, db_s, json_s) = (b.to_str().expect("utf8"), db.to_str().expect("utf8"), json.to_str().expect("utf8"));
    let o = odocal(&["follow", &a, b_s, "--vehicle", "van", "--db", db_s, "--json", json_s]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v = json_file(&json);
    let drives = v["drives"].as_array().expect("drives");
    assert_eq!(drives[0]["fingerprint"], sidecar["drive_fingerprint"]);
    assert_ne!(drives[1]["fingerprint"], drives[0]["fingerprint"], "parts are part of the fingerprint");
    assert_eq!(drives[1]["samples"], drives[0]["samples"]);
    assert!(drives[1]["validation_segments"].as_u64().expect("segments") > 0, "{}", drives[1]);

    // A row out of time order: the whole reader's message, with its line.
    let bad = dir.path().join("bad.csv");
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    lines.swap(100, 101);
    std::fs::write(&bad, lines.join("\n") + "\n").expect("write");
    let bad_s = bad.to_str().expect("utf8");
    let o = odocal(&["follow", bad_s, "--vehicle", "van", "--db", db_s]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let c = odocal(&["calibrate", bad_s, "--method", "batch-gn"]);
    let message = |s: String| s.lines().find(|l| l.contains("line 102")).map(str::to_owned);
    assert!(message(stderr(&o)).is_some(), "{}", stderr(&o));
    assert_eq!(message(stderr(&o)), message(stderr(&c)), "{}", stderr(&c));
}

/// A shipped test-track manifest, road bank and all, is followed as a
/// stream (no note of a whole import), with the whole import's samples:
/// the fingerprint, samples and prequential error of the drive `odocal
/// import` writes from it.
#[test]
fn follow_streams_a_shipped_banked_manifest_with_the_whole_imports_samples() {
    let dir = tempfile::tempdir().expect("tempdir");
    let m = format!("{}/../../examples/psu-mapping-van-testtrack/run-16-06-28.toml", env!("CARGO_MANIFEST_DIR"));
    assert!(std::fs::read_to_string(&m).expect("manifest").contains("[lateral_acceleration.bank]"));
    let path = |name: &str| dir.path().join(name).to_str().expect("utf8").to_owned();
    let csv = path("run.csv");
    let o = odocal(&["import", &m, "--out", &csv]);
    assert!(o.status.success(), "{}", stderr(&o));
    let mut drives = Vec::new();
    for (input, db, json) in [(&m, path("a.sqlite"), path("a.json")), (&csv, path("b.sqlite"), path("b.json"))] {
        let o = odocal(&["follow", input, "--vehicle", "van", "--db", &db, "--json", &json]);
        assert!(o.status.success(), "{}", stderr(&o));
        if input == &m {
            assert!(stderr(&o).contains("as a stream"), "{}", stderr(&o));
            assert!(!stderr(&o).contains("imported whole"), "{}", stderr(&o));
        }
        drives.push(json_file(std::path::Path::new(&json))["drives"][0].clone());
    }
    for key in ["fingerprint", "samples", "validation_segments", "prequential_mean_position_error_m"] {
        assert_eq!(drives[0][key], drives[1][key], "{key}");
    }
    assert!(drives[0]["validation_segments"].as_u64().expect("segments") > 0);
}

/// The calibrator's and the gates' settings are flags under their own
/// headings in `--help-all` (not in `-h`/`--help`), and they act.
#[test]
fn follow_exposes_the_online_and_gate_settings() {
    let help = stdout(&odocal(&["follow", "--help-all"]));
    let online = help.find("Online calibrator:").expect("heading");
    let gates = help.find("Write-back gates:").expect("heading");
    for flag in ["--sigma-factors", "--random-walk", "--prior-sd", "--information-scale", "--informative-yaw-rate"] {
        let at = help.find(&format!("--{}", &flag[2..])).unwrap_or_else(|| panic!("{flag}:\n{help}"));
        assert!(at > online, "{flag} not under its heading:\n{help}");
    }
    assert!(gates < online, "{help}");
    for flag in ["--steady-s", "--max-sigma", "--max-change"] {
        assert!(help[gates..online].contains(flag), "{flag} not under its heading:\n{help}");
    }
    assert!(help.contains("1.1,4.6,6.3,4.1"), "{help}");
    for short in ["-h", "--help"] {
        assert!(!stdout(&odocal(&["follow", short])).contains("--sigma-factors"));
    }

    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--seed", "9", "--length-km", "2"]);
    let run = |name: &str, extra: &[&str]| {
        let db = dir.path().join(format!("{name}.sqlite"));
        let json = dir.path().join(format!("{name}.json"));
        let mut args = vec!["follow", a.as_str(), "--vehicle", "van", "--db", db.to_str().expect("utf8")];
        args.extend(["--json", json.to_str().expect("utf8")]);
        args.extend_from_slice(extra);
        let o = odocal(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        json_file(&json)["drives"][0]["updates"][0].clone()
    };
    let plain = run("plain", &[]);
    let doubled = run("doubled", &["--sigma-factors", "2.2,9.2,12.6,8.2"]);
    assert_eq!(plain["theta"], doubled["theta"]);
    for p in ["c_e", "c_d", "t_r", "d"] {
        let (s1, s2) = (plain["sigma"][p].as_f64().expect("σ"), doubled["sigma"][p].as_f64().expect("σ"));
        assert!((s2 / s1 - 2.0).abs() < 1e-9, "{p}: {s1} {s2}");
    }
    // A σ threshold no estimate meets holds the update, naming the gate.
    let held = run("held", &["--max-sigma", "1e-12,1e-12,1e-12,1e-12"]);
    assert_eq!(held["decision"], "held", "{held}");
    assert!(held["reasons"][0].as_str().expect("reason").starts_with("σ of c_e"), "{held}");
    // Bad values: usage errors naming the flag.
    let db = dir.path().join("bad.sqlite");
    let db = db.to_str().expect("utf8");
    let o = odocal(&["follow", &a, "--vehicle", "v", "--db", db, "--random-walk", "1,2,3"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let o = odocal(&["follow", &a, "--vehicle", "v", "--db", db, "--sigma-factors", "1,0,1,1"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--sigma-factors = 1,0,1,1"), "{}", stderr(&o));
    let o = odocal(&["follow", &a, "--vehicle", "v", "--db", db, "--max-change", "1,1,1,-1"]);
    assert!(stderr(&o).contains("--max-change must be four positive numbers"), "{}", stderr(&o));
}

/// Nothing claims a start that did not happen: with a first drive that
/// cannot be read, `follow` prints no "starting from" line, only the
/// error naming the drive; a good first drive is read before the line,
/// and a bad second one is named after it.
#[test]
fn follow_claims_its_start_only_once_the_first_drive_was_read() {
    let dir = tempfile::tempdir().expect("tempdir");
    let good = simulated_drive(dir.path(), "good.csv", &["--seed", "3", "--length-km", "1"]);
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "t,px,py,psi,n_rl,n_rr,beta,a_y\n0,0,0,0,5,5,0,0\n0.025,0.25,0,0,x,5,0,0\n").expect("write");
    let (bad_s, db) = (bad.to_str().expect("utf8"), dir.path().join("h.sqlite"));
    let db_s = db.to_str().expect("utf8");
    let o = odocal(&["follow", bad_s, &good, "--vehicle", "van", "--db", db_s]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(!stdout(&o).contains("starting from"), "a start claimed before the drive was read: {}", stdout(&o));
    assert!(stderr(&o).contains(&format!("{bad_s}: line 3, column 'n_rl'")), "{}", stderr(&o));
    let o = odocal(&["follow", &good, bad_s, "--vehicle", "van", "--db", db_s]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    let out = stdout(&o);
    let start = out.find("vehicle 'van': starting from").expect("the start, after the first drive was read");
    let followed = out.find(&format!("{good}: prequential")).expect("the good drive followed");
    assert!(start < followed, "{out}");
    assert!(stderr(&o).contains(&format!("{bad_s}: line 3")), "{}", stderr(&o));
}

/// One drive calibrated by two methods is one drive in `history`: both
/// rows are listed, the earlier stands aside (in the text and the JSON),
/// the pooled estimate is over one drive and no drift is flagged between
/// the two methods' estimates of it.
#[test]
fn history_counts_a_drive_calibrated_twice_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--seed", "8", "--length-km", "3"]);
    let db = dir.path().join("h.sqlite");
    let db_s = db.to_str().expect("utf8");
    for method in ["batch-gn", "three-step"] {
        let o = odocal(&["calibrate", &a, "--method", method, "--vehicle", "van", "--db", db_s]);
        assert!(o.status.code() != Some(1), "{}", stderr(&o));
    }
    let o = odocal(&["history", "van", "--db", db_s, "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: Value = serde_json::from_str(&stdout(&o)).expect("history json");
    assert_eq!(v["rows"].as_array().expect("rows").len(), 2, "{v}");
    assert_eq!(v["set_aside"], serde_json::json!([{"id": 1, "by_id": 2}]), "{v}");
    assert_eq!(v["drift"], serde_json::json!([]), "{v}");
    let p = &v["pooled"];
    assert_eq!((p["rows"].as_u64(), p["drives"].as_u64()), (Some(1), Some(1)), "{p}");
    assert_eq!(p["mean"], v["rows"][1]["theta"], "the later row's θ: {p}");
    let text = stdout(&odocal(&["history", "van", "--db", db_s]));
    assert!(
        text.contains("row 1 stands aside for row 2") && text.contains("pooled over 1 drive(s) in 1 row(s)"),
        "{text}"
    );
}

/// `--params-out -` keeps stdout for the parameter file alone: the text
/// report goes to stderr, and of several written updates stdout gets the
/// last, once (what the file would hold at the end), a file that reads
/// back. Each written file carries the verdict `accepted`.
#[test]
fn follow_params_to_stdout_is_one_parameter_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--seed", "1", "--length-km", "4", "--noise", "off"]);
    let b = simulated_drive(dir.path(), "b.csv", &["--seed", "2", "--length-km", "4", "--noise", "off"]);
    let db = dir.path().join("h.sqlite");
    let db_s = db.to_str().expect("utf8");
    let o = odocal(&["follow", &a, &b, "--vehicle", "van", "--db", db_s, "--params-out", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (out, err) = (stdout(&o), stderr(&o));
    assert!(err.contains("starting from") && err.contains(&format!("{b}: prequential")), "{err}");
    assert_eq!(out.matches("ros__parameters:").count(), 1, "{out}");
    assert!(!out.contains("prequential") && !out.contains("starting from"), "{out}");
    assert!(out.contains("verdict: \"accepted\"") && out.contains("verdict_reasons: [\"all gates passed"), "{out}");
    let written = history_rows(db_s);
    let last = written.last().expect("a written update");
    let yaml = dir.path().join("p.yaml");
    std::fs::write(&yaml, &out).expect("write");
    let o = odocal(&["validate", &b, "--theta", yaml.to_str().expect("utf8")]);
    assert!(o.status.success(), "{}", stderr(&o));
    let c_e = last["theta"]["c_e"].as_f64().expect("c_e");
    assert!(out.contains(&format!("c_e: {c_e:?}")), "the last written update: {out}");
}

/// A calibration with `d` held is recorded with the σ of c_e, c_d and t_r
/// and `d` marked held; `history` leaves its `d` (θ_0's) out of d's pooled
/// estimate, which is the other row's measurement, and prints no NaN.
#[test]
fn history_keeps_each_sigma_and_pools_no_held_value() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("h.sqlite");
    let db_s = db.to_str().expect("utf8");
    for (name, seed, fix) in [("a.csv", "1", Some("d")), ("b.csv", "2", None)] {
        let d = simulated_drive(dir.path(), name, &["--seed", seed, "--length-km", "4"]);
        // EIV: a batch-gn row would name input_noise_bias on these drives and not be pooled at all.
        let mut args = vec!["calibrate", &d, "--vehicle", "van", "--db", db_s];
        if let Some(p) = fix {
            args.extend(["--fix", p]);
        }
        let o = odocal(&args);
        assert!(o.status.code() != Some(1), "{}", stderr(&o));
    }
    let o = odocal(&["history", "van", "--db", db_s, "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: Value = serde_json::from_str(&stdout(&o)).expect("history json");
    let rows = v["rows"].as_array().expect("rows");
    assert_eq!(rows[0]["held"], serde_json::json!(["d"]), "{}", rows[0]);
    for p in ["c_e", "c_d", "t_r"] {
        assert!(rows[0]["sigma"][p].as_f64().is_some_and(|s| s > 0.0), "{p}: {}", rows[0]);
    }
    assert!(rows[0]["sigma"]["d"].is_null(), "{}", rows[0]);
    assert_eq!(v["pooled"]["mean"]["d"], rows[1]["theta"]["d"], "{}", v["pooled"]);
    let text = stdout(&odocal(&["history", "van", "--db", db_s]));
    assert!(text.contains(" held ") && text.contains("not pooled: row 1 held"), "{text}");
    assert!(!text.contains("NaN"), "{text}");
}

/// `calibrate --vehicle --db` records the verdict's reason kinds; a
/// batch-gn row naming `input_noise_bias` is listed but not pooled, so the
/// drive's EIV row stands for it in the pool, and the text names the row.
#[test]
fn history_does_not_pool_a_row_whose_verdict_names_a_bias() {
    let dir = tempfile::tempdir().expect("tempdir");
    let db = dir.path().join("h.sqlite");
    let db_s = db.to_str().expect("utf8");
    // Heavy white wheel noise: batch G-N's bias exceeds its σ.
    let d = simulated_drive(dir.path(), "a.csv", &["--seed", "2", "--length-km", "4", "--noise", "high"]);
    for method in ["eiv", "batch-gn"] {
        let o = odocal(&["calibrate", &d, "--method", method, "--vehicle", "van", "--db", db_s]);
        assert!(o.status.code() != Some(1), "{}", stderr(&o));
    }
    let o = odocal(&["history", "van", "--db", db_s, "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: Value = serde_json::from_str(&stdout(&o)).expect("history json");
    let rows = v["rows"].as_array().expect("rows");
    assert!(rows[1]["reasons"].as_array().expect("reasons").iter().any(|k| k == "input_noise_bias"), "{}", rows[1]);
    assert!(rows[0]["reasons"].as_array().is_some_and(|k| !k.iter().any(|k| k == "input_noise_bias")), "{}", rows[0]);
    assert_eq!(
        v["pooled"]["biased"],
        serde_json::json!([{"id": 2, "reasons": ["input_noise_bias"]}]),
        "{}",
        v["pooled"]
    );
    // One drive pooled: its own c_e, to the rounding of the weighted mean.
    let (pooled, own) = (v["pooled"]["mean"]["c_e"].as_f64(), rows[0]["theta"]["c_e"].as_f64());
    assert!(pooled.zip(own).is_some_and(|(p, o)| (p - o).abs() <= 1e-12 * o.abs()), "{}", v["pooled"]);
    let text = stdout(&odocal(&["history", "van", "--db", db_s]));
    assert!(text.contains("not pooled, the verdict names a bias beyond its σ: row 2 (input_noise_bias)"), "{text}");
}

/// A written update rests on every drive the recursion followed: its
/// parameter file names them all, in order, as `calibrate` names a joint
/// fit's drives (`input` and `fingerprint` comma separated), counts them,
/// and says where the recursion started.
#[test]
fn follow_params_name_every_drive_the_update_rests_on() {
    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--seed", "1", "--length-km", "4", "--noise", "off"]);
    let b = simulated_drive(dir.path(), "b.csv", &["--seed", "2", "--length-km", "4", "--noise", "off"]);
    let (db, json, params) = (dir.path().join("h.sqlite"), dir.path().join("f.json"), dir.path().join("p.json"));
    let path = |p: &std::path::Path| p.to_str().expect("utf8").to_owned();
    let (db_s, json_s, params_s) = (path(&db), path(&json), path(&params));
    // Turning segments only: the default threshold 0 also folds the
    // noise-free drives' exactly straight stretches, after which the second
    // drive's update is no better than the first's on its last validation
    // segments (0.8 mm against 0.3 mm) and is held, not written.
    let o = odocal(&[
        "follow",
        &a,
        &b,
        "--vehicle",
        "van",
        "--db",
        &db_s,
        "--json",
        &json_s,
        "--params-out",
        &params_s,
        "--min-yaw-rate",
        "1e-6",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let drives = json_file(&json)["drives"].as_array().expect("drives").clone();
    assert_eq!(drives[1]["updates"][0]["decision"], "written", "{}", drives[1]);
    let prints: Vec<&str> = drives.iter().map(|d| d["fingerprint"].as_str().expect("fingerprint")).collect();
    let prov = json_file(&params)["provenance"].clone();
    assert_eq!(prov["input"].as_str(), Some(format!("{a}, {b}").as_str()), "{prov}");
    assert_eq!(prov["fingerprint"].as_str(), Some(prints.join(", ").as_str()), "{prov}");
    assert_eq!(prov["drives"].as_str(), Some("2"), "{prov}");
    assert_eq!(prov["start"].as_str(), Some("θ_0"), "{prov}");
    assert_eq!(prov["method"].as_str(), Some("online"), "{prov}");
}

/// `--db` that cannot be a history written to is refused before the work:
/// `-` (no file named `-` is created), a file that is no history database
/// (`calibrate` writes no `--json` and names the file once). `history`
/// changes no file: an empty one is refused and stays empty. `history
/// --report - --json FILE` writes both.
#[test]
fn history_files_are_checked_before_the_work_and_read_without_a_change() {
    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--seed", "4", "--length-km", "3"]);
    let cwd = tempfile::tempdir().expect("cwd");
    for args in [
        vec!["follow", a.as_str(), "--vehicle", "van", "--db", "-"],
        vec!["calibrate", a.as_str(), "--method", "batch-gn", "--vehicle", "van", "--db", "-"],
    ] {
        let o = crate::common::odocal_in(cwd.path(), &args);
        assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
        assert!(stderr(&o).contains("--db -: the history is a database file"), "{}", stderr(&o));
        assert!(!cwd.path().join("-").exists(), "{args:?} created a file named -");
    }
    let bad = dir.path().join("bad.sqlite");
    std::fs::write(&bad, "not a database\n".repeat(100)).expect("write");
    let json = dir.path().join("r.json");
    let (bad_s, json_s) = (bad.to_str().expect("utf8"), json.to_str().expect("utf8"));
    let o = odocal(&["calibrate", &a, "--method", "batch-gn", "--vehicle", "van", "--db", bad_s, "--json", json_s]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert_eq!(stderr(&o).matches("bad.sqlite").count(), 1, "{}", stderr(&o));
    assert!(!json.exists(), "the work ran before the history was checked");
    // `history` on an empty file: refused, the file left empty.
    let empty = dir.path().join("empty.sqlite");
    std::fs::write(&empty, b"").expect("empty");
    let o = odocal(&["history", "van", "--db", empty.to_str().expect("utf8")]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("an empty file, not a history database"), "{}", stderr(&o));
    assert_eq!(std::fs::metadata(&empty).expect("meta").len(), 0);
    // A history read is left as it was, and both outputs are written.
    let db = dir.path().join("h.sqlite");
    let db_s = db.to_str().expect("utf8");
    let o = odocal(&["calibrate", &a, "--method", "batch-gn", "--vehicle", "van", "--db", db_s]);
    assert!(o.status.code() != Some(1), "{}", stderr(&o));
    let before = std::fs::read(&db).expect("db");
    let o = odocal(&["history", "van", "--db", db_s, "--report", "-", "--json", json_s]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).starts_with("<!DOCTYPE html>"), "{}", stdout(&o));
    assert_eq!(json_file(&json)["rows"].as_array().expect("rows").len(), 1);
    assert_eq!(std::fs::read(&db).expect("db"), before, "history changed the file");
}

/// An SQLite file of another application given as `--db` is refused by
/// `calibrate` and `follow` as `history` refuses it, naming the file, and
/// left as it was; a FIFO is named as not a regular file.
#[test]
fn another_applications_sqlite_file_is_not_taken_over() {
    let dir = tempfile::tempdir().expect("tempdir");
    let a = simulated_drive(dir.path(), "a.csv", &["--length-km", "2"]);
    let app = dir.path().join("app.db");
    let conn = rusqlite::Connection::open(&app).expect("open");
    conn.execute_batch("CREATE TABLE users (x);").expect("table");
    drop(conn);
    let before = std::fs::read(&app).expect("read");
    let app_s = app.to_str().expect("utf8");
    for args in [
        vec!["calibrate", a.as_str(), "--method", "batch-gn", "--vehicle", "v1", "--db", app_s],
        vec!["follow", a.as_str(), "--vehicle", "v1", "--db", app_s],
        vec!["history", "v1", "--db", app_s],
    ] {
        let o = odocal(&args);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(e.contains(&format!("{app_s}: history database: ")), "{e}");
        if args[0] != "history" {
            assert!(e.contains("another application (its tables: 'users'), not an odocal history"), "{e}");
        }
    }
    assert_eq!(std::fs::read(&app).expect("read"), before, "the file was changed");
    assert!(!dir.path().join("app.db-wal").exists());
    let fifo = dir.path().join("fifo");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
    let o = odocal(&["history", "v1", "--db", fifo.to_str().expect("utf8")]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("not a regular file") && !stderr(&o).contains("empty"), "{}", stderr(&o));
}

/// The highway van's manifest (`clock_offset = "auto"`) imported whole by
/// `calibrate` and as a stream by `follow` gives two fingerprints (the
/// stream decides the clock offset on its first 300 s): `follow` knows the
/// drive by its files and time all the same, and skips it.
#[test]
fn follow_skips_a_manifest_calibrate_imported_whole() {
    let dir = tempfile::tempdir().expect("tempdir");
    let m = format!("{}/../../examples/psu-mapping-van/manifest.toml", env!("CARGO_MANIFEST_DIR"));
    let path = |name: &str| dir.path().join(name).to_str().expect("utf8").to_owned();
    let (db, json) = (path("h.sqlite"), path("f.json"));
    let o = odocal(&["calibrate", &m, "--method", "batch-gn", "--vehicle", "van", "--db", &db]);
    assert!(stderr(&o).contains("recorded in"), "{}", stderr(&o));
    let o = odocal(&["follow", &m, "--vehicle", "van", "--db", &db, "--json", &json]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("as a stream"), "{}", stderr(&o));
    assert!(stdout(&o).contains("already recorded"), "{}", stdout(&o));
    let followed = &json_file(std::path::Path::new(&json))["drives"][0];
    assert_eq!(followed["already_recorded"], true, "{followed}");
    let rows = history_rows(&db);
    assert_eq!(rows.len(), 1);
    assert_ne!(rows[0]["fingerprint"], followed["fingerprint"], "the test needs two fingerprints");
    assert_eq!(rows[0]["source_digest"].as_str().map(str::len), Some(64), "{}", rows[0]);
}

/// A drive that cannot be read stops the replay, and the drives before it
/// stay recorded: `--json` still reports them, with the error and the
/// drive the replay stopped at, written as every output is; before any
/// drive was handled nothing was done and no JSON is written.
#[test]
fn follow_json_reports_the_drives_recorded_before_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let g1 = simulated_drive(dir.path(), "g1.csv", &["--seed", "3", "--length-km", "1"]);
    let g2 = simulated_drive(dir.path(), "g2.csv", &["--seed", "4", "--length-km", "1"]);
    let g4 = simulated_drive(dir.path(), "g4.csv", &["--seed", "5", "--length-km", "1"]);
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "t,px,py,psi,n_rl,n_rr,beta,a_y\n0,0,0,0,5,5,0,0\n0.025,0.25,0,0,x,5,0,0\n").expect("write");
    let (bad_s, db) = (bad.to_str().expect("utf8"), dir.path().join("h.sqlite"));
    let db_s = db.to_str().expect("utf8");
    let json = dir.path().join("f.json");
    let json_s = json.to_str().expect("utf8");
    let o = odocal(&["follow", &g1, &g2, bad_s, &g4, "--vehicle", "van", "--db", db_s, "--json", json_s]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains(&format!("error: {bad_s}: line 3")), "{}", stderr(&o));
    let v = json_file(&json);
    let drives = v["drives"].as_array().expect("drives");
    let sources: Vec<&str> = drives.iter().map(|d| d["source"].as_str().expect("source")).collect();
    assert_eq!(sources, [g1.as_str(), g2.as_str()], "{v}");
    assert!(drives.iter().all(|d| d["updates"].as_array().expect("updates").len() == 1), "{v}");
    assert_eq!(v["error"]["drive"], bad_s, "{v}");
    assert_eq!(v["error"]["drive_number"], 3, "{v}");
    let message = v["error"]["message"].as_str().expect("message");
    assert!(stderr(&o).contains(&format!("error: {message}\n")), "{message} | {}", stderr(&o));
    // The history holds each drive the JSON reports: followed again, both are skipped.
    let json3 = dir.path().join("f3.json");
    let o = odocal(&["follow", &g1, &g2, "--vehicle", "van", "--db", db_s, "--json", json3.to_str().expect("utf8")]);
    assert!(o.status.success(), "{}", stderr(&o));
    let again = json_file(&json3);
    assert!(again["drives"].as_array().expect("drives").iter().all(|d| d["already_recorded"] == true), "{again}");

    // Stopped at its first drive: nothing done, no JSON.
    let json2 = dir.path().join("f2.json");
    let o = odocal(&["follow", bad_s, &g4, "--vehicle", "van", "--db", db_s, "--json", json2.to_str().expect("utf8")]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(!json2.exists(), "a JSON of nothing done");
    // Without an error the JSON has no `error`.
    let o = odocal(&["follow", &g4, "--vehicle", "van", "--db", db_s, "--json", json_s]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(json_file(&json).as_object().expect("object").keys().collect::<Vec<_>>(), vec!["drives"]);
}

/// Two shipped test-track runs given against the order they were driven
/// are followed, with a warning naming both and their clocks' first
/// stamps, in one `follow` run or in two; in the order driven there is
/// none.
#[test]
fn follow_warns_of_drives_given_out_of_the_order_driven() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run =
        |name: &str| format!("{}/../../examples/psu-mapping-van-testtrack/run-{name}.toml", env!("CARGO_MANIFEST_DIR"));
    let (early, late) = (run("14-45-26"), run("15-28-33"));
    let db = |name: &str| dir.path().join(name).to_str().expect("utf8").to_owned();
    let o = odocal(&["follow", &late, &early, "--vehicle", "van", "--db", &db("a.sqlite")]);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    let warning = err.lines().find(|l| l.contains("was recorded")).unwrap_or_else(|| panic!("no warning: {err}"));
    assert!(warning.starts_with(&format!("warning: {early} was recorded 2587 s before {late}")), "{warning}");
    assert!(warning.contains("give the drives in the order they were driven"), "{warning}");
    let o = odocal(&["follow", &early, &late, "--vehicle", "van", "--db", &db("b.sqlite")]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("was recorded"), "{}", stderr(&o));
    // Across runs: the history keeps the last drive's first stamp.
    let o = odocal(&["follow", &late, "--vehicle", "van", "--db", &db("c.sqlite")]);
    assert!(o.status.success() && !stderr(&o).contains("was recorded"), "{}", stderr(&o));
    let o = odocal(&["follow", &early, "--vehicle", "van", "--db", &db("c.sqlite")]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains(&format!("warning: {early} was recorded 2587 s before {late}")), "{}", stderr(&o));
}
