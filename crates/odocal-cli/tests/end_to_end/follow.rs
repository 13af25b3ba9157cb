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
    let rows = history_rows(db_s);
    assert!(!rows.is_empty());
    assert!(rows.iter().all(|r| r["method"] == "online"));

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
}
