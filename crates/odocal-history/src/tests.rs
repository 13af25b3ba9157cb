use super::*;

fn theta(c_e: f64) -> Theta {
    Theta { c_e, c_d: -0.002, t_r: 1.53, d: 0.0008 }
}

/// A simulated drive of `km` without noise (the `off` preset), from the
/// paper's route of `seed`.
fn noise_free_drive(km: f64, seed: u64) -> odocal::Drive {
    let noise = "off".parse().expect("the off preset");
    let sim = odocal::sim::SimOptions { length_km: km, noise, ..odocal::sim::SimOptions::paper(seed) };
    odocal::sim::simulate(&sim).expect("sim").drive
}

fn sigma(s: f64) -> ParamSigma {
    Theta { c_e: s, c_d: s, t_r: s, d: s }.into()
}

fn record(vehicle: &str, fp: &str, c_e: f64, s: f64) -> CalibrationRecord {
    CalibrationRecord {
        sources: vec![format!("{fp}.csv")],
        t_start_s: 0.0,
        t_end_s: 60.0,
        sigma: sigma(s),
        verdict: Some("trusted".into()),
        heading_offset_rad: Some(0.01),
        ..CalibrationRecord::new(vehicle, fp, "eiv", theta(c_e))
    }
}

/// A `--db` that is a drive CSV or a folder is named with what to give
/// instead, and the file is left as it was.
#[test]
fn a_file_or_folder_that_is_no_history_says_what_to_give() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("drive.csv");
    let text = "t,px,py,psi,n_rl,n_rr,beta,a_y\n".repeat(200);
    std::fs::write(&csv, &text).expect("write");
    for (path, what) in [(&csv, "not an SQLite file"), (&dir.path().to_path_buf(), "a folder, not a file")] {
        let e = History::open(path).map(|_| ()).expect_err("not a history").to_string();
        assert!(e.contains(what) && e.contains("the name of a new file to start a history"), "{e}");
    }
    assert_eq!(std::fs::read_to_string(&csv).expect("read"), text);
}

/// An SQLite file of another application given as `--db` is refused by
/// name before anything in it changes: its tables, schema version and
/// journal mode stay as they were, and the reader refuses it alike.
#[test]
fn an_sqlite_file_of_another_application_is_refused_and_left_as_it_was() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (name, setup, what) in [
        ("app.db", "CREATE TABLE users (x);", "another application (its tables: 'users')"),
        ("app3.db", "CREATE TABLE users (x); PRAGMA user_version = 3;", "schema version 3 without a history's tables"),
        ("bare3.db", "PRAGMA user_version = 3;", "schema version 3 without a history's tables"),
        ("id.db", "PRAGMA application_id = 1234;", "another application (application_id 0x4d2)"),
    ] {
        let path = dir.path().join(name);
        let conn = Connection::open(&path).expect("open");
        conn.execute_batch(setup).expect("setup");
        drop(conn);
        let before = std::fs::read(&path).expect("read");
        let e = History::open(&path).map(|_| ()).expect_err("not a history").to_string();
        assert!(e.starts_with(&format!("{}: history database: ", path.display())), "{e}");
        assert!(e.contains(what) && e.contains("not an odocal history"), "{e}");
        assert!(e.contains("the name of a new file to start a history"), "{e}");
        assert_eq!(std::fs::read(&path).expect("read"), before, "{name} changed");
        assert!(!dir.path().join(format!("{name}-wal")).exists(), "{name} switched to WAL");
        assert!(History::open_read_only(&path).is_err());
    }
}

/// A history whose migration fails (a damaged file: a column the
/// migration adds is there already) says so, naming the file.
#[test]
fn a_failed_migration_says_the_file_is_damaged_or_no_history() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("h.sqlite");
    let conn = Connection::open(&path).expect("open");
    for sql in &schema::MIGRATIONS[..4] {
        conn.execute_batch(sql).expect("migration");
    }
    conn.pragma_update(None, "user_version", 3).expect("pragma");
    drop(conn);
    let e = History::open(&path).map(|_| ()).expect_err("damaged").to_string();
    assert!(
        e.starts_with(&format!("{}: history database: migration to schema version 4 failed", path.display())),
        "{e}"
    );
    assert!(e.contains("not an odocal history of schema version 3, or a damaged one"), "{e}");
}

/// A FIFO or a device given as the history is named as not a regular
/// file, by the writer and the reader, without opening it.
#[test]
fn a_fifo_or_device_is_not_a_regular_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fifo = dir.path().join("fifo");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo");
    assert!(made.success());
    for path in [fifo.as_path(), Path::new("/dev/null")] {
        for e in [History::open(path).map(|_| ()), History::open_read_only(path).map(|_| ())] {
            let e = e.expect_err("not a file").to_string();
            assert!(e.contains("not a regular file") && !e.contains("empty"), "{e}");
        }
    }
}

#[test]
fn an_empty_file_is_migrated_to_the_current_schema() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("h.sqlite");
    std::fs::write(&path, b"").expect("empty file");
    let db = History::open(&path).expect("open");
    assert_eq!(db.schema_version, schema::SCHEMA_VERSION);
    assert!(db.rows("v").expect("rows").is_empty());
    drop(db);
    // Reopening runs no migration again.
    let db = History::open(&path).expect("reopen");
    assert_eq!(db.schema_version, schema::SCHEMA_VERSION);
}

#[test]
fn a_newer_schema_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("h.sqlite");
    let conn = Connection::open(&path).expect("open");
    conn.pragma_update(None, "user_version", schema::SCHEMA_VERSION + 1).expect("pragma");
    drop(conn);
    let e = History::open(&path).expect_err("newer");
    assert!(e.to_string().contains("newer"), "{e}");
}

#[test]
fn a_drive_is_recorded_once_per_vehicle_and_method() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let rec = record("van", "fp1", 1.95, 1e-3);
    let Recorded::New(id) = db.record(&rec).expect("first") else { panic!("not new") };
    assert_eq!(db.record(&rec).expect("second"), Recorded::AlreadyRecorded(id));
    // Another method, another vehicle: new rows.
    assert!(matches!(db.record(&CalibrationRecord { method: "online".into(), ..rec.clone() }), Ok(Recorded::New(_))));
    assert!(matches!(db.record(&CalibrationRecord { vehicle: "car".into(), ..rec.clone() }), Ok(Recorded::New(_))));
    let rows = db.rows("van").expect("rows");
    assert_eq!(rows.len(), 2);
    assert_eq!(rows[0].record, rec);
    assert_eq!(rows[0].odocal_version, env!("CARGO_PKG_VERSION"));
    assert!(rows[0].recorded_at.ends_with('Z') && rows[0].recorded_at.len() == 24, "{}", rows[0].recorded_at);
    assert_eq!(db.rows("van").expect("rows").last().map(|r| r.id), Some(rows[1].id));
    assert!(db.rows("none").expect("rows").is_empty());
    assert_eq!(db.vehicles().expect("vehicles"), ["car", "van"]);
    let empty = History::open(dir.path().join("empty.sqlite")).expect("open");
    assert!(empty.vehicles().expect("vehicles").is_empty());
}

#[test]
fn concurrent_writers_lose_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("h.sqlite");
    let threads: Vec<_> = (0..4)
        .map(|t| {
            let path = path.clone();
            std::thread::spawn(move || {
                let mut db = History::open(&path).expect("open");
                for i in 0..25 {
                    // Every thread also records the shared drives "s0".."s4".
                    db.record(&record("van", &format!("t{t}-{i}"), 1.95, 1e-3)).expect("record");
                    db.record(&record("van", &format!("s{}", i % 5), 1.95, 1e-3)).expect("record shared");
                    // Every thread also decides on the shared drives: one
                    // decision each is logged, by whichever thread is first.
                    for fingerprint in [format!("t{t}-{i}"), format!("s{}", i % 5)] {
                        db.record_followed(
                            &DecisionRow {
                                id: 0,
                                decided_at: String::new(),
                                odocal_version: String::new(),
                                vehicle: "van".into(),
                                fingerprint,
                                source: "x".into(),
                                source_digest: None,
                                t_start_s: None,
                                clock_start_s: None,
                                drive_time_s: i as f64,
                                decision: "held".into(),
                                reasons: vec!["sigma".into()],
                                theta: theta(1.95),
                                sigma: None,
                            },
                            None,
                        )
                        .expect("decision");
                    }
                }
            })
        })
        .collect();
    for t in threads {
        t.join().expect("thread");
    }
    let db = History::open(&path).expect("open");
    assert_eq!(db.rows("van").expect("rows").len(), 4 * 25 + 5);
    assert_eq!(db.decision_count("van").expect("count"), 100 + 5);
    let check: String = db.conn.query_row("PRAGMA integrity_check", [], |r| r.get(0)).expect("check");
    assert_eq!(check, "ok");
}

#[test]
fn drift_is_flagged_beyond_three_combined_sigma() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    // σ = 1 mm each: combined 1.414 mm, threshold 4.24 mm.
    db.record(&record("van", "a", 1.950, 1e-3)).expect("a");
    db.record(&record("van", "b", 1.954, 1e-3)).expect("b"); // 4 mm: not flagged
    db.record(&record("van", "c", 1.960, 1e-3)).expect("c"); // 6 mm: flagged
    let flags = db.vehicle("van", None).expect("history").drift;
    assert_eq!(flags.len(), 1, "{flags:?}");
    assert_eq!(flags[0].parameter, "c_e");
    assert!((flags[0].change - 0.006).abs() < 1e-12);
    assert!((flags[0].combined_sigma - 2f64.sqrt() * 1e-3).abs() < 1e-15);
    let rows = db.rows("van").expect("rows");
    assert_eq!((flags[0].from_id, flags[0].to_id), (rows[1].id, rows[2].id));
}

#[test]
fn pooled_is_the_inverse_variance_mean() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    db.record(&record("van", "a", 1.0, 1.0)).expect("a");
    db.record(&record("van", "b", 2.0, 0.5)).expect("b");
    let p = db.vehicle("van", None).expect("history").pooled.expect("rows");
    // Weights 1 and 4: (1 + 8) / 5.
    assert!((p.mean.c_e - 1.8).abs() < 1e-12);
    assert!((p.between_drive_sd.c_e - 0.5f64.sqrt()).abs() < 1e-12);
    // Model se 1/√5 = 0.447 against spread se 0.5: the larger.
    assert!((p.sigma_of_mean.c_e - 0.5).abs() < 1e-12);
    let first = db.rows("van").expect("rows")[0].id;
    let one = db.vehicle("van", Some(&[first])).expect("history").pooled.expect("rows");
    assert_eq!(one.rows, 1);
    assert!((one.mean.c_e - 1.0).abs() < 1e-12 && one.between_drive_sd.c_e.is_nan());
    assert!(db.vehicle("none", None).expect("history").pooled.is_none());
}

#[test]
fn the_table_shows_each_sigma_in_its_values_unit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let sd = Theta { c_e: 1.7e-3, c_d: 3.1e-4, t_r: 4.6e-3, d: 9.8e-5 };
    db.record(&CalibrationRecord { sigma: sd.into(), ..record("van", "a", 1.95, 1e-3) }).expect("a");
    let shifted = Theta { c_d: -0.0004, ..theta(1.95) };
    db.record(&CalibrationRecord { theta: shifted, sigma: sd.into(), ..record("van", "b", 1.95, 1e-3) }).expect("b");
    let text = db.vehicle("van", None).expect("history").to_string();
    let lines: Vec<&str> = text.lines().collect();
    // c_d = -2 mm ± 0.31 mm, d = 0.8 mm/(m/s²) ± 0.098 mm/(m/s²): value and σ in one unit.
    assert!(lines[0].contains("c_d (mm)") && lines[0].contains("d (mm/(m/s²))"), "{text}");
    assert!(lines[1].contains("-2.000±3.1e-1") && lines[1].contains("0.800±9.8e-2"), "{text}");
    assert!(!text.contains("mm/g"), "{text}");
    // The c_d change of 1.6 mm against a combined σ of 0.44 mm.
    assert!(text.contains("c_d row 1 (") && text.contains("+1.6000e0 mm (combined σ 4.38e-1 mm, 3.6σ)"), "{text}");
    let pooled_c_d = format!("  c_d  {:<10} {:>12.6} ± 8.00e-1   between-drive sd 1.13e0\n", "mm", -1.2);
    assert!(text.contains(&pooled_c_d), "{text}");
}

#[test]
fn the_table_lists_each_row_the_drift_and_the_pooled_estimate() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    db.record(&record("van", "a", 1.950, 1e-3)).expect("a");
    let one = db.vehicle("van", None).expect("history").to_string();
    let lines: Vec<&str> = one.lines().collect();
    assert!(lines[0].starts_with("  id  recorded (UTC)") && lines[0].ends_with("verdict   source"), "{one}");
    assert!(lines[1].contains(" eiv ") && lines[1].contains("1.95000±1.0e-3") && lines[1].ends_with("trusted   a.csv"));
    assert!(one.contains("\nno drift: consecutive rows agree within 3 combined σ\n"), "{one}");
    assert!(one.contains("pooled over 1 drive(s) in 1 row(s) (") && one.contains("— (needs two drives)"), "{one}");
    db.record(&record("van", "c", 1.960, 1e-3)).expect("c");
    let two = db.vehicle("van", None).expect("history").to_string();
    assert!(two.contains("drift (|Δ| > 3·sqrt(σ₁² + σ₂²)):\n  c_e row 1 ("), "{two}");
    assert!(!two.contains("needs two drives"), "{two}");
}

/// A flag between rows whose σ is the model's alone says it is no evidence
/// of drift; the same change between rows with checked σ does not.
#[test]
fn a_drift_flag_on_a_model_only_sigma_says_so() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let model_only = |fp: &str, c_e: f64, flag: Option<bool>| CalibrationRecord {
        sigma_model_only: flag,
        method: "batch-gn".into(),
        ..record("van", fp, c_e, 1e-4)
    };
    db.record(&model_only("a", 1.950, Some(false))).expect("a");
    db.record(&model_only("b", 1.951, Some(true))).expect("b");
    db.record(&model_only("c", 1.952, None)).expect("c");
    db.record(&model_only("d", 1.953, Some(false))).expect("d");
    let h = db.vehicle("van", None).expect("history");
    assert_eq!(h.rows[1].record.sigma_model_only, Some(true));
    assert_eq!(h.rows[2].record.sigma_model_only, None);
    let flags: Vec<(i64, bool)> = h.drift.iter().map(|f| (f.to_id, f.model_sigma_only)).collect();
    let ids: Vec<i64> = h.rows.iter().map(|r| r.id).collect();
    assert_eq!(flags, vec![(ids[1], true), (ids[2], true), (ids[3], false)], "{:?}", h.drift);
    assert!(h.drift.iter().all(|f| !f.biased), "no row names a bias: {:?}", h.drift);
    let text = h.to_string();
    assert_eq!(text.matches(MODEL_SIGMA_NOTE).count(), 2, "{text}");
    let json = serde_json::to_value(&h.drift).expect("json");
    assert_eq!(json[0]["model_sigma_only"], true);
    assert_eq!(json[2]["model_sigma_only"], false);
}

/// A version-1 file gains the column on opening; its rows read as not known.
#[test]
fn a_version_one_file_is_migrated_and_keeps_its_rows() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("h.sqlite");
    let conn = Connection::open(&path).expect("open");
    conn.execute_batch(schema::MIGRATIONS[0]).expect("version 1");
    conn.pragma_update(None, "user_version", 1).expect("pragma");
    conn.execute(
        "INSERT INTO calibrations (vehicle, recorded_at, fingerprint, sources, t_start_s, t_end_s, method, \
         c_e, c_d, t_r, d, odocal_version) VALUES ('van', '2026-01-01T00:00:00.000Z', 'f', '[]', 0, 1, 'eiv', \
         1.95, 0, 1.5, 0, '0.2.0')",
        [],
    )
    .expect("row");
    drop(conn);
    let db = History::open(&path).expect("migrate");
    assert_eq!(db.schema_version, schema::SCHEMA_VERSION);
    let rows = db.rows("van").expect("rows");
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0].record.sigma_model_only, None);
    assert_eq!(rows[0].record.theta.c_e.to_bits(), 1.95f64.to_bits());
}

/// `of_report` records whether the σ is the model's alone: batch G-N on a
/// 3 km drive (no cluster-robust σ) yes, on a 12 km drive no.
#[test]
fn a_calibration_records_whether_its_sigma_is_the_models_alone() {
    let record_of = |km: f64| {
        let sim = odocal::sim::SimOptions { length_km: km, ..odocal::sim::SimOptions::paper(1) };
        let drive = odocal::sim::simulate(&sim).expect("sim").drive;
        let opts = odocal::CalibrationOptions { method: "batch-gn".parse().expect("method"), ..Default::default() };
        let r = odocal::calibrate(&drive, &opts).expect("calibrate");
        let rec = CalibrationRecord::of_report("van", "f", Vec::new(), (0.0, 1.0), &r);
        // The verdict's reason kinds, as its JSON names them.
        let kinds: Vec<String> = serde_json::to_value(&r.verdict.reasons)
            .expect("json")
            .as_array()
            .expect("reasons")
            .iter()
            .map(|x| x["kind"].as_str().expect("kind").to_string())
            .collect();
        assert_eq!(rec.reasons.as_ref(), Some(&kinds));
        let named = kinds.iter().any(|k| k == "model_sigma_only");
        assert_eq!(rec.sigma_model_only, Some(named));
        rec.sigma_model_only
    };
    assert_eq!(record_of(3.0), Some(true));
    assert_eq!(record_of(12.0), Some(false));
}

/// `follow` from a row whose σ is the model's alone starts the recursion
/// from the prior's sd, not from that σ: its estimate after a drive is as
/// uncertain as one started without a σ, and wider than one started from
/// the same σ checked against the data.
#[test]
fn follow_does_not_start_from_a_model_only_sigma() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("a.csv");
    let sim = odocal::sim::SimOptions { length_km: 1.0, ..odocal::sim::SimOptions::paper(4) };
    odocal::sim::simulate(&sim).expect("sim").drive.write_csv(&csv).expect("csv");
    let truth = odocal::sim::SimOptions::default().theta_true;
    let tight = Theta { c_e: 1e-6, c_d: 1e-7, t_r: 1e-5, d: 1e-7 };
    let follow_from = |name: &str, sigma: Option<Theta>, model_only: Option<bool>| {
        let mut db = History::open(dir.path().join(name)).expect("open");
        let row = CalibrationRecord {
            sigma: sigma.map_or_else(ParamSigma::default, ParamSigma::from),
            sigma_model_only: model_only,
            ..CalibrationRecord::new("van", "start", "batch-gn", truth)
        };
        db.record(&row).expect("row");
        let (mut origin, mut sd) = (String::new(), None);
        follow(&mut db, "van", std::slice::from_ref(&csv), &FollowOptions::default(), |e| {
            match e {
                FollowEvent::Start { origin: o, .. } => origin = o,
                FollowEvent::Followed { decision, .. } => sd = Some(decision.sigma),
                _ => {}
            }
            Ok::<(), Error>(())
        })
        .expect("follow");
        (origin, sd.expect("followed"))
    };
    let (origin, model_only) = follow_from("a.sqlite", Some(tight), Some(true));
    assert!(origin.contains("its σ is the model's alone"), "{origin}");
    let (_, checked) = follow_from("b.sqlite", Some(tight), Some(false));
    let (plain, without) = follow_from("c.sqlite", None, None);
    assert!(!plain.contains("model's alone"), "{plain}");
    assert_eq!(model_only, without, "the prior's sd, as without a σ");
    assert!(model_only.t_r > 10.0 * checked.t_r, "{model_only:?} vs {checked:?}");
}

/// A row whose σ is the model's alone does not outweigh the others: the
/// rows are pooled by their plain mean.
#[test]
fn a_model_only_sigma_does_not_weigh_the_pooled_estimate() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    db.record(&record("van", "a", 1.950, 1e-3)).expect("a");
    db.record(&record("van", "b", 1.954, 1e-3)).expect("b");
    let tight = CalibrationRecord {
        sigma_model_only: Some(true),
        method: "batch-gn".into(),
        ..record("van", "c", 1.958, 1e-5)
    };
    db.record(&tight).expect("c");
    let p = db.vehicle("van", None).expect("history").pooled.expect("rows");
    assert!((p.mean.c_e - 1.954).abs() < 1e-12, "{p:?}");
    // The same row with its σ checked dominates the inverse-variance mean.
    let mut db = History::open(dir.path().join("g.sqlite")).expect("open");
    db.record(&record("van", "a", 1.950, 1e-3)).expect("a");
    db.record(&record("van", "b", 1.954, 1e-3)).expect("b");
    db.record(&CalibrationRecord { sigma_model_only: Some(false), ..tight }).expect("c");
    let p = db.vehicle("van", None).expect("history").pooled.expect("rows");
    assert!((p.mean.c_e - 1.958).abs() < 1e-5, "{p:?}");
}

/// One drive calibrated by two methods is two estimates from the same
/// samples, not two drives: the drift flags and the pooled estimate take
/// its most recent row, the other stands aside (listed, and said), so the
/// pooled σ does not shrink as if the drive had been driven twice and the
/// methods' difference is not flagged as drift.
#[test]
fn a_drive_recorded_by_several_methods_counts_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let a_eiv = db.record(&record("van", "a", 1.950, 1e-3)).expect("a eiv");
    // The same drive by another method, 10 mm away: 7 combined σ.
    let a_gn = CalibrationRecord { method: "batch-gn".into(), ..record("van", "a", 1.960, 1e-3) };
    let a_gn = db.record(&a_gn).expect("a batch-gn");
    let b = db.record(&record("van", "b", 1.962, 1e-3)).expect("b");
    let (Recorded::New(a_eiv), Recorded::New(a_gn), Recorded::New(b)) = (a_eiv, a_gn, b) else {
        panic!("three new rows")
    };
    let h = db.vehicle("van", None).expect("history");
    assert_eq!(h.rows.len(), 3, "every row listed");
    assert_eq!(h.set_aside, [SetAside { id: a_eiv, by_id: a_gn }]);
    assert!(h.drift.is_empty(), "no drift between two rows of one drive: {:?}", h.drift);
    let p = h.pooled.as_ref().expect("pooled");
    assert_eq!((p.rows, p.drives), (2, 2), "{p:?}");
    assert_eq!(p.set_aside, [SetAside { id: a_eiv, by_id: a_gn }]);
    assert!((p.mean.c_e - 1.961).abs() < 1e-12, "{p:?}");
    // Two drives 2 mm apart: the between-drive sd is theirs alone.
    assert!((p.between_drive_sd.c_e - 2f64.sqrt() * 1e-3).abs() < 1e-12, "{p:?}");
    let text = h.to_string();
    let said = format!("each drive counted once, by its most recent row: row {a_eiv} stands aside for row {a_gn}");
    assert!(text.contains(&said), "{text}");
    let pooled = format!("pooled over 2 drive(s) in 2 row(s); row {a_eiv} stands aside for row {a_gn} (");
    assert!(text.contains(&pooled), "{text}");
    assert_eq!(text.lines().filter(|l| l.contains(" a.csv")).count(), 2, "{text}");
    // --pool naming both rows of the drive still pools it once, by the later.
    let p = db.vehicle("van", Some(&[a_eiv, a_gn])).expect("history").pooled.expect("pooled");
    assert_eq!((p.rows, p.drives, p.mean.c_e), (1, 1, 1.960), "{p:?}");
    // --pool naming the earlier row alone pools it.
    let p = db.vehicle("van", Some(&[a_eiv, b])).expect("history").pooled.expect("pooled");
    assert_eq!((p.rows, p.drives, p.set_aside.len()), (2, 2, 0), "{p:?}");
    assert!((p.mean.c_e - 1.956).abs() < 1e-12, "{p:?}");
}

/// A rejected result is listed but neither flagged nor pooled, and a
/// rejected later row of a drive leaves the drive's earlier row standing.
#[test]
fn a_rejected_row_is_listed_but_neither_flagged_nor_pooled() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let rejected = |fp: &str, c_e: f64| CalibrationRecord {
        verdict: Some("rejected".into()),
        method: "batch-gn".into(),
        ..record("van", fp, c_e, 1e-4)
    };
    let ids: Vec<i64> =
        [record("van", "a", 1.950, 1e-3), rejected("a", 1.5), record("van", "b", 1.952, 1e-3), rejected("c", 0.9)]
            .iter()
            .map(|r| match db.record(r).expect("record") {
                Recorded::New(id) => id,
                other => panic!("{other:?}"),
            })
            .collect();
    let h = db.vehicle("van", None).expect("history");
    assert_eq!(h.rows.len(), 4, "every row listed");
    assert!(h.set_aside.is_empty() && h.drift.is_empty(), "{:?} {:?}", h.set_aside, h.drift);
    let p = h.pooled.as_ref().expect("pooled");
    assert_eq!((p.rows, p.drives, &p.rejected), (2, 2, &vec![ids[1], ids[3]]), "{p:?}");
    assert!((p.mean.c_e - 1.951).abs() < 1e-12, "{p:?}");
    let text = h.to_string();
    assert!(text.contains(&format!("not pooled, verdict rejected: rows {}, {}", ids[1], ids[3])), "{text}");
    // Only rejected rows: nothing to pool.
    assert!(db.vehicle("van", Some(&[ids[1], ids[3]])).expect("history").pooled.is_none());
    // `follow` starts from the most recent row that is not rejected.
    let csv = dir.path().join("d.csv");
    noise_free_drive(1.0, 3).write_csv(&csv).expect("csv");
    let mut start = None;
    follow(&mut db, "van", std::slice::from_ref(&csv), &FollowOptions::default(), |e| {
        if let FollowEvent::Start { theta, origin } = e {
            start = Some((theta, origin));
        }
        Ok::<(), Error>(())
    })
    .expect("follow");
    let (theta, origin) = start.expect("a start");
    assert_eq!((theta.c_e, origin), (1.952, format!("history row {}", ids[2])));
}

/// A joint calibration holds each of its drives (its fingerprint names
/// them, comma separated): the rows of those drives alone recorded before
/// it stand aside for it, and it counts as its drives.
#[test]
fn a_joint_calibration_stands_for_each_of_its_drives() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    for (fp, c_e) in [("a", 1.950), ("b", 1.952), ("a, b", 1.951), ("c", 1.953)] {
        db.record(&record("van", fp, c_e, 1e-3)).expect("row");
    }
    let ids: Vec<i64> = db.rows("van").expect("rows").iter().map(|r| r.id).collect();
    let h = db.vehicle("van", None).expect("history");
    assert_eq!(h.set_aside, [SetAside { id: ids[0], by_id: ids[2] }, SetAside { id: ids[1], by_id: ids[2] }]);
    let p = h.pooled.as_ref().expect("pooled");
    assert_eq!((p.rows, p.drives), (2, 3), "{p:?}");
    assert!(h.to_string().contains(&format!("rows {}, {} stand aside for row {}", ids[0], ids[1], ids[2])));
}

/// `follow` does not replay a drive the history holds a calibration of (by
/// any method): its samples would count twice, in the recursion that
/// starts from that calibration and in the history. It says which row
/// holds it and adds nothing.
#[test]
fn follow_skips_a_drive_the_history_holds_a_calibration_of() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("a.csv");
    let drive = noise_free_drive(1.0, 2);
    drive.write_csv(&csv).expect("csv");
    let fingerprint = odocal::Drive::read_csv(&csv).expect("read").0.fingerprint();
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    // Calibrated jointly with another drive, by EIV.
    let joint = format!("{}, {fingerprint}", "f".repeat(64));
    let Recorded::New(id) = db.record(&record("van", &joint, 1.95, 1e-3)).expect("row") else { panic!("new row") };
    let mut events = Vec::new();
    follow(&mut db, "van", std::slice::from_ref(&csv), &FollowOptions::default(), |e| {
        events.push(e);
        Ok::<(), Error>(())
    })
    .expect("follow");
    assert!(
        matches!(&events[..], [FollowEvent::Skipped { row: Some((r, m)), .. }] if *r == id && m == "eiv"),
        "{events:?}"
    );
    assert_eq!(db.rows("van").expect("rows").len(), 1);
    assert_eq!(db.decision_count("van").expect("decisions"), 0);
}

/// `follow` judges each drive before the calibrator sees it: a wheel
/// logged as zeros for 100 s of driving stops the replay with an error
/// naming the file, the column and the samples, after the drive before it
/// was followed and recorded; the bad drive leaves no decision.
#[test]
fn follow_refuses_a_drive_with_a_lost_signal() {
    let dir = tempfile::tempdir().expect("tempdir");
    let sim = |seed| {
        odocal::sim::simulate(&odocal::sim::SimOptions { length_km: 3.0, ..odocal::sim::SimOptions::paper(seed) })
            .expect("sim")
            .drive
    };
    let good = dir.path().join("good.csv");
    sim(1).write_csv(&good).expect("csv");
    let d = sim(2);
    let mut s = d.measured().clone();
    s.n_rl[2000..6000].iter_mut().for_each(|v| *v = 0.0);
    let lost = dir.path().join("lost.csv");
    odocal::DriveBuilder { t: d.t().to_vec(), measured: s, ..Default::default() }
        .build()
        .expect("drive")
        .write_csv(&lost)
        .expect("csv");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let mut followed = Vec::new();
    let e = follow(&mut db, "van", &[good, lost.clone()], &FollowOptions::default(), |e| {
        if let FollowEvent::Followed { source, .. } = e {
            followed.push(source);
        }
        Ok::<(), Error>(())
    })
    .expect_err("the lost signal is refused")
    .to_string();
    assert!(e.contains(&lost.display().to_string()) && e.contains("column 'n_rl' reads (almost) no rotation"), "{e}");
    assert!(e.contains("samples 2000–"), "{e}");
    assert_eq!(followed.len(), 1, "{followed:?}");
    assert_eq!(db.decision_count("van").expect("decisions"), 1);
}

/// A row with `d` held keeps the σ of the parameters it measured; its `d`
/// (θ_0's value, no measurement) is listed but takes no part in `d`'s
/// drift flags or pooled estimate, and a parameter no pooled row measured
/// has no pooled value. No value prints as NaN.
#[test]
fn a_held_parameter_keeps_the_others_sigma_and_is_not_pooled() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let held = CalibrationRecord {
        theta: Theta { d: 0.0, ..theta(1.950) },
        sigma: ParamSigma { d: None, ..sigma(1e-4) },
        held: vec!["d".into()],
        ..record("van", "a", 1.950, 1e-4)
    };
    let Recorded::New(a) = db.record(&held).expect("a") else { panic!("new") };
    let measured = CalibrationRecord { theta: Theta { d: 7e-4, ..theta(1.9502) }, ..record("van", "b", 1.9502, 1e-4) };
    let Recorded::New(b) = db.record(&measured).expect("b") else { panic!("new") };
    let h = db.vehicle("van", None).expect("history");
    assert_eq!(h.rows[0].record, held, "σ and held read back per parameter");
    assert_eq!(h.rows[0].record.sigma.c_e, Some(1e-4));
    // 0.7 mm/(m/s²) between θ_0's 0 and a measurement of σ 0.1: no drift.
    assert!(h.drift.is_empty(), "{:?}", h.drift);
    let p = h.pooled.as_ref().expect("pooled");
    assert!((p.mean.d - 7e-4).abs() < 1e-15, "d pooled over the row that measured it: {p:?}");
    assert!((p.sigma_of_mean.d - 1e-4).abs() < 1e-15, "{p:?}");
    assert!(p.between_drive_sd.d.is_nan(), "one measured row");
    assert!((p.mean.c_e - 1.9501).abs() < 1e-12, "c_e pooled over both: {p:?}");
    assert_eq!(p.not_measured, [NotMeasured { id: a, parameter: "d".into(), why: "held".into() }]);
    let text = h.to_string();
    assert!(text.contains(" 0.000 held ") && text.contains("held: held at θ_0"), "{text}");
    assert!(text.contains(&format!("not pooled: row {a} held")), "{text}");
    assert!(!text.contains("NaN"), "{text}");
    // The held row alone: d has no pooled value, and says so.
    let h = db.vehicle("van", Some(&[a])).expect("history");
    let p = h.pooled.as_ref().expect("pooled");
    assert!(p.mean.d.is_nan() && (p.mean.c_e - 1.950).abs() < 1e-12, "{p:?}");
    let text = h.to_string();
    assert!(text.contains("— no measured row (held or not observable in every row pooled)"), "{text}");
    assert!(!text.contains("NaN"), "{text}");
    // A single row without σ: no σ of the mean, said in words.
    let mut db = History::open(dir.path().join("g.sqlite")).expect("open");
    db.record(&CalibrationRecord::new("van", "c", "eiv", theta(1.95))).expect("c");
    let text = db.vehicle("van", None).expect("history").to_string();
    assert!(text.contains("± — (one row, without σ)") && !text.contains("NaN"), "{text}");
    let _ = b;
}

/// A parameter named not observable is left out as a held one is.
#[test]
fn an_unobservable_parameter_is_not_pooled() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let unobs = CalibrationRecord {
        theta: Theta { t_r: 1.6, ..theta(1.950) },
        unobservable: vec!["t_r".into()],
        ..record("van", "a", 1.950, 1e-3)
    };
    let Recorded::New(a) = db.record(&unobs).expect("a") else { panic!("new") };
    db.record(&record("van", "b", 1.950, 1e-3)).expect("b");
    let h = db.vehicle("van", None).expect("history");
    assert_eq!(h.rows[0].record.unobservable, ["t_r"]);
    let p = h.pooled.as_ref().expect("pooled");
    assert!((p.mean.t_r - 1.53).abs() < 1e-12, "{p:?}");
    assert_eq!(p.not_measured, [NotMeasured { id: a, parameter: "t_r".into(), why: "not observable".into() }]);
    assert!(h.to_string().contains(" 1.600 unobs."), "{h}");
}

/// `of_report` of a calibration with `d` held stores the σ of the three
/// free parameters and marks `d` held.
#[test]
fn a_calibration_with_a_held_parameter_records_the_others_sigma() {
    let sim = odocal::sim::SimOptions { length_km: 3.0, ..odocal::sim::SimOptions::paper(1) };
    let drive = odocal::sim::simulate(&sim).expect("sim").drive;
    let mut opts = odocal::CalibrationOptions { method: "batch-gn".parse().expect("method"), ..Default::default() };
    opts.identify.free = "c_e,c_d,t_r".parse().expect("free");
    let r = odocal::calibrate(&drive, &opts).expect("calibrate");
    let rec = CalibrationRecord::of_report("van", "f", Vec::new(), (0.0, 1.0), &r);
    assert_eq!(rec.held, ["d"]);
    let s = rec.sigma;
    assert!(s.c_e.is_some() && s.c_d.is_some() && s.t_r.is_some() && s.d.is_none(), "{s:?}");
}

/// A version-2 file gains the columns of held and unobservable parameters
/// on opening: its rows read as measured, and its online rows (updates
/// every write-back gate passed) as accepted.
#[test]
fn a_version_two_file_is_migrated_and_keeps_its_rows() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("h.sqlite");
    let conn = Connection::open(&path).expect("open");
    conn.execute_batch(schema::MIGRATIONS[0]).expect("version 1");
    conn.execute_batch(schema::MIGRATIONS[1]).expect("version 2");
    conn.pragma_update(None, "user_version", 2).expect("pragma");
    for (fp, method) in [("a", "eiv"), ("b", "online")] {
        conn.execute(
            "INSERT INTO calibrations (vehicle, recorded_at, fingerprint, sources, t_start_s, t_end_s, method, \
             c_e, c_d, t_r, d, sigma_c_e, sigma_c_d, sigma_t_r, sigma_d, odocal_version) VALUES ('van', \
             '2026-01-01T00:00:00.000Z', ?1, '[]', 0, 1, ?2, 1.95, 0, 1.5, 0, 1e-3, 1e-4, 1e-2, 1e-4, '0.2.0')",
            params![fp, method],
        )
        .expect("row");
    }
    drop(conn);
    let db = History::open(&path).expect("migrate");
    assert_eq!(db.schema_version, schema::SCHEMA_VERSION);
    let rows = db.rows("van").expect("rows");
    assert_eq!(rows.len(), 2);
    assert!(rows.iter().all(|r| r.record.held.is_empty() && r.record.unobservable.is_empty()));
    assert_eq!(rows[0].record.sigma, ParamSigma::from(Theta { c_e: 1e-3, c_d: 1e-4, t_r: 1e-2, d: 1e-4 }));
    assert_eq!(rows[0].record.verdict, None);
    assert_eq!(rows[1].record.verdict.as_deref(), Some("accepted"));
}

/// Online rows are running estimates, each holding the drives before it:
/// listed and drift-flagged, but not pooled with the offline calibrations
/// (or with each other); with online rows alone nothing is pooled, and the
/// most recent is named as the estimate.
#[test]
fn online_rows_are_listed_but_not_pooled() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let online = |fp: &str, c_e: f64| CalibrationRecord { method: ONLINE.into(), ..record("van", fp, c_e, 1e-4) };
    let ids: Vec<i64> = [record("van", "a", 1.950, 1e-3), online("b", 1.951), online("c", 1.9525)]
        .iter()
        .map(|r| match db.record(r).expect("record") {
            Recorded::New(id) => id,
            other => panic!("{other:?}"),
        })
        .collect();
    let h = db.vehicle("van", None).expect("history");
    let p = h.pooled.as_ref().expect("pooled");
    assert_eq!((p.rows, p.drives, &p.online), (1, 1, &vec![ids[1], ids[2]]), "{p:?}");
    assert!((p.mean.c_e - 1.950).abs() < 1e-12, "{p:?}");
    // 1.5 mm between the online rows against a combined σ of 0.14 mm: flagged.
    assert_eq!(h.drift.iter().map(|f| f.to_id).collect::<Vec<_>>(), [ids[2]], "{:?}", h.drift);
    let text = h.to_string();
    assert!(text.contains(&format!("not pooled, online running estimates: rows {}, {}", ids[1], ids[2])), "{text}");
    let h = db.vehicle("van", Some(&ids[1..])).expect("history");
    assert!(h.pooled.is_none());
    let text = h.to_string();
    assert!(text.contains("nothing pooled: the rows are online running estimates"), "{text}");
    assert!(
        text.contains(&format!("the most recent, row {}, is the estimate follow continues from\n", ids[2])),
        "{text}"
    );
    assert!(!text.contains("every drive followed"), "{text}");
}

/// After held drives (whose data `follow` drops) the most recent online
/// row is not called the estimate over every drive followed: the text says
/// how many drives followed after it are not in it.
#[test]
fn held_drives_after_the_last_online_row_are_named_as_not_in_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let decision = |fp: &str, action: &str| DecisionRow {
        id: 0,
        decided_at: String::new(),
        odocal_version: String::new(),
        vehicle: "van".into(),
        fingerprint: fp.into(),
        source: format!("{fp}.csv"),
        source_digest: None,
        t_start_s: None,
        clock_start_s: None,
        drive_time_s: 60.0,
        decision: action.into(),
        reasons: vec![],
        theta: theta(1.95),
        sigma: None,
    };
    let online = |fp: &str| CalibrationRecord { method: ONLINE.into(), ..record("van", fp, 1.95, 1e-4) };
    db.record_followed(&decision("a", "held"), None).expect("a");
    db.record_followed(&decision("b", "written"), Some(&online("b"))).expect("b");
    let text = db.vehicle("van", None).expect("history").to_string();
    assert!(text.contains("is the estimate follow continues from\n"), "{text}");
    db.record_followed(&decision("c", "held"), None).expect("c");
    db.record_followed(&decision("d", "flagged"), None).expect("d");
    let text = db.vehicle("van", None).expect("history").to_string();
    assert!(text.contains("2 drives followed after it were held or flagged, and their data are not in it"), "{text}");
    assert!(!text.contains("every drive followed"), "{text}");
}

/// Two `follow` runs of one vehicle on one database at once: each drive is
/// decided once (the second run to finish a drive skips it), and every
/// online row `follow` writes says `accepted`.
#[test]
fn concurrent_follows_decide_each_drive_once() {
    let dir = tempfile::tempdir().expect("tempdir");
    let drives: Vec<std::path::PathBuf> = (1..=2)
        .map(|seed| {
            let csv = dir.path().join(format!("d{seed}.csv"));
            noise_free_drive(1.5, seed).write_csv(&csv).expect("csv");
            csv
        })
        .collect();
    let path = dir.path().join("h.sqlite");
    History::open(&path).expect("create");
    let runs: Vec<_> = (0..2)
        .map(|_| {
            let (path, drives) = (path.clone(), drives.clone());
            std::thread::spawn(move || {
                let mut db = History::open(&path).expect("open");
                follow(&mut db, "van", &drives, &FollowOptions::default(), |_| Ok::<(), Error>(())).expect("follow");
            })
        })
        .collect();
    for r in runs {
        r.join().expect("run");
    }
    let db = History::open(&path).expect("open");
    let decisions = db.decisions("van").expect("decisions");
    let mut prints: Vec<&str> = decisions.iter().map(|d| d.fingerprint.as_str()).collect();
    prints.sort_unstable();
    prints.dedup();
    assert_eq!((decisions.len(), prints.len()), (2, 2), "{decisions:?}");
    let rows = db.rows("van").expect("rows");
    assert!(rows.iter().all(|r| r.record.verdict.as_deref() == Some("accepted")), "{rows:?}");
}

/// A record the CLI could not have made (a blank vehicle, an unknown
/// method, θ beyond the physical limits, a σ that is no σ) is refused
/// before anything is written.
#[test]
fn a_record_is_checked_before_it_is_written() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let good = record("van", "fp1", 1.95, 1e-3);
    let cases = [
        (
            CalibrationRecord { vehicle: " ".into(), ..good.clone() },
            "invalid option `vehicle`: the vehicle's identifier is empty",
        ),
        (CalibrationRecord { vehicle: "van ".into(), ..good.clone() }, "has a space at an end"),
        (CalibrationRecord { vehicle: "a\nb".into(), ..good.clone() }, "'a\\nb' holds a control character"),
        (
            CalibrationRecord { method: "foo".into(), ..good.clone() },
            "invalid option `method`: 'foo' is not a method of odocal's: eiv, three-step, batch-gn, online",
        ),
        (CalibrationRecord { method: " eiv".into(), ..good.clone() }, "' eiv' is not a method"),
        (CalibrationRecord { theta: theta(2000.0), ..good.clone() }, "c_e = 2000 m is outside 0.05 … 20 m"),
        (
            CalibrationRecord { theta: Theta { t_r: f64::NAN, ..theta(1.95) }, ..good.clone() },
            "t_r = NaN is not finite",
        ),
        (
            CalibrationRecord { sigma: ParamSigma { d: Some(-1e-4), ..sigma(1e-3) }, ..good.clone() },
            "invalid option `sigma`: d = -0.0001",
        ),
        (CalibrationRecord { sigma: sigma(f64::NAN), ..good.clone() }, "c_e = NaN: a standard deviation"),
        (
            CalibrationRecord { held: vec!["x".into()], ..good.clone() },
            "invalid option `held`: 'x' is not a parameter of θ",
        ),
        (
            CalibrationRecord { unobservable: vec!["lever_x".into()], ..good.clone() },
            "invalid option `unobservable`: 'lever_x' is not a parameter of θ",
        ),
    ];
    for (rec, want) in cases {
        let e = db.record(&rec).expect_err(want).to_string();
        assert!(e.contains(want), "{e}");
    }
    assert!(db.vehicles().expect("vehicles").is_empty(), "nothing written");
    for method in METHODS {
        assert!(matches!(
            db.record(&CalibrationRecord { method: method.into(), ..good.clone() }),
            Ok(Recorded::New(_))
        ));
    }
}

/// A written decision and its calibration row are one transaction: when
/// the row cannot be inserted (here a trigger aborts every insert into
/// `calibrations`), the decision is not logged either, so the drive is
/// not taken for followed and a later run decides it again.
#[test]
fn a_written_decision_is_not_logged_without_its_calibration_row() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    db.conn
        .execute_batch(
            "CREATE TRIGGER no_rows BEFORE INSERT ON calibrations BEGIN SELECT RAISE(ABORT, 'injected'); END;",
        )
        .expect("trigger");
    let decision = DecisionRow {
        id: 0,
        decided_at: String::new(),
        odocal_version: String::new(),
        vehicle: "van".into(),
        fingerprint: "fp".into(),
        source: "fp.csv".into(),
        source_digest: None,
        t_start_s: None,
        clock_start_s: None,
        drive_time_s: 60.0,
        decision: "written".into(),
        reasons: vec!["every gate passed".into()],
        theta: theta(1.95),
        sigma: Some(Theta { c_e: 1e-4, c_d: 1e-4, t_r: 1e-3, d: 1e-4 }),
    };
    let rec = CalibrationRecord { method: ONLINE.into(), ..record("van", "fp", 1.95, 1e-4) };
    let e = db.record_followed(&decision, Some(&rec)).expect_err("the row's insert fails");
    assert!(e.to_string().contains("injected"), "{e}");
    assert_eq!(db.decision_count("van").expect("count"), 0, "a decision without its row");
    assert!(db.rows("van").expect("rows").is_empty());
    // Without the failure both are written.
    db.conn.execute_batch("DROP TRIGGER no_rows;").expect("drop");
    assert!(db.record_followed(&decision, Some(&rec)).expect("written").is_some());
    assert_eq!((db.decision_count("van").expect("count"), db.rows("van").expect("rows").len()), (1, 1));
}

/// Reading a history changes nothing: an empty file and an SQLite file
/// without a history's tables are refused and left as they were, a history
/// of this schema is read in place, one of an older schema from a migrated
/// copy (the file keeps its version and bytes).
#[test]
fn reading_a_history_changes_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    let empty = dir.path().join("empty.sqlite");
    std::fs::write(&empty, b"").expect("empty");
    let e = History::open_read_only(&empty).map(|_| ()).expect_err("empty").to_string();
    assert!(e.contains("an empty file, not a history database"), "{e}");
    assert_eq!(std::fs::metadata(&empty).expect("meta").len(), 0);
    let other = dir.path().join("other.sqlite");
    Connection::open(&other).expect("open").execute_batch("CREATE TABLE t (x);").expect("table");
    let before = std::fs::read(&other).expect("read");
    let e = History::open_read_only(&other).map(|_| ()).expect_err("no history").to_string();
    assert!(e.contains("without a history's tables"), "{e}");
    assert_eq!(std::fs::read(&other).expect("read"), before);
    let missing = dir.path().join("missing.sqlite");
    assert!(History::open_read_only(&missing).is_err());
    assert!(!missing.exists());
    // A version-1 file: read through a migrated copy, left at version 1.
    let old = dir.path().join("old.sqlite");
    let conn = Connection::open(&old).expect("open");
    conn.execute_batch(schema::MIGRATIONS[0]).expect("version 1");
    conn.pragma_update(None, "user_version", 1).expect("pragma");
    conn.execute(
        "INSERT INTO calibrations (vehicle, recorded_at, fingerprint, sources, t_start_s, t_end_s, method, \
         c_e, c_d, t_r, d, odocal_version) VALUES ('van', '2026-01-01T00:00:00.000Z', 'f', '[]', 0, 1, 'eiv', \
         1.95, 0, 1.5, 0, '0.2.0')",
        [],
    )
    .expect("row");
    drop(conn);
    let before = std::fs::read(&old).expect("read");
    let db = History::open_read_only(&old).expect("read only");
    assert_eq!(db.vehicle("van", None).expect("history").rows.len(), 1);
    drop(db);
    assert_eq!(std::fs::read(&old).expect("read"), before);
    // A current history is read in place.
    let path = dir.path().join("h.sqlite");
    History::open(&path).expect("create").record(&record("van", "a", 1.95, 1e-3)).expect("record");
    let db = History::open_read_only(&path).expect("read only");
    assert_eq!(db.rows("van").expect("rows").len(), 1);
    assert!(db.conn.is_readonly(rusqlite::MAIN_DB).expect("flag"));
}

/// `follow` from a row that names a parameter not observable starts the
/// recursion from the prior's sd, as without a σ: that parameter's σ is no
/// measure of it.
#[test]
fn follow_does_not_start_from_the_sigma_of_a_parameter_not_observable() {
    let dir = tempfile::tempdir().expect("tempdir");
    let csv = dir.path().join("a.csv");
    let sim = odocal::sim::SimOptions { length_km: 1.0, ..odocal::sim::SimOptions::paper(4) };
    odocal::sim::simulate(&sim).expect("sim").drive.write_csv(&csv).expect("csv");
    let truth = odocal::sim::SimOptions::default().theta_true;
    let tight = Theta { c_e: 1e-6, c_d: 1e-7, t_r: 1e-5, d: 1e-7 };
    let follow_from = |name: &str, sigma: Option<Theta>, unobservable: &[&str]| {
        let mut db = History::open(dir.path().join(name)).expect("open");
        let row = CalibrationRecord {
            sigma: sigma.map_or_else(ParamSigma::default, ParamSigma::from),
            sigma_model_only: Some(false),
            unobservable: unobservable.iter().map(|p| p.to_string()).collect(),
            ..CalibrationRecord::new("van", "start", "eiv", truth)
        };
        db.record(&row).expect("row");
        let (mut origin, mut sd) = (String::new(), None);
        follow(&mut db, "van", std::slice::from_ref(&csv), &FollowOptions::default(), |e| {
            match e {
                FollowEvent::Start { origin: o, .. } => origin = o,
                FollowEvent::Followed { decision, .. } => sd = Some(decision.sigma),
                _ => {}
            }
            Ok::<(), Error>(())
        })
        .expect("follow");
        (origin, sd.expect("followed"))
    };
    let (origin, unobservable) = follow_from("a.sqlite", Some(tight), &["t_r"]);
    assert!(origin.contains("t_r not observable in it, so the prior's sd"), "{origin}");
    let (_, observed) = follow_from("b.sqlite", Some(tight), &[]);
    let (_, without) = follow_from("c.sqlite", None, &[]);
    assert_eq!(unobservable, without, "the prior's sd, as without a σ");
    assert!(unobservable.t_r > 10.0 * observed.t_r, "{unobservable:?} vs {observed:?}");
}

/// A batch-gn row whose verdict names `input_noise_bias` (or
/// `heading_offset_held`) is listed and drift-flagged but not pooled: the
/// EIV row of its drive stands for the drive in the pool, the text and the
/// JSON name the row and its reason; a row whose reasons are not known is
/// pooled.
#[test]
fn a_row_whose_verdict_names_a_bias_is_listed_but_not_pooled() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let gn = |fp: &str, c_e: f64, kind: &str| CalibrationRecord {
        method: "batch-gn".into(),
        verdict: Some("doubtful".into()),
        reasons: Some(vec!["model_sigma_only".into(), kind.into()]),
        ..record("van", fp, c_e, 1e-4)
    };
    let unknown = record("van", "a", 1.950, 1e-3);
    assert_eq!(unknown.reasons, None);
    let ids: Vec<i64> = [unknown, gn("a", 1.960, "input_noise_bias"), gn("b", 1.990, "heading_offset_held")]
        .iter()
        .map(|r| match db.record(r).expect("record") {
            Recorded::New(id) => id,
            other => panic!("{other:?}"),
        })
        .collect();
    let rows = db.rows("van").expect("rows");
    assert_eq!(rows[0].record.reasons, None, "not known");
    assert_eq!(
        rows[1].record.reasons.as_deref(),
        Some(&["model_sigma_only".to_string(), "input_noise_bias".into()][..])
    );
    let h = db.vehicle("van", None).expect("history");
    let p = h.pooled.as_ref().expect("pooled");
    assert_eq!((p.rows, p.drives), (1, 1), "{p:?}");
    assert_eq!(p.mean.c_e.to_bits(), 1.950f64.to_bits(), "the EIV row alone: {p:?}");
    let biased: Vec<(i64, Vec<String>)> = p.biased.iter().map(|b| (b.id, b.reasons.clone())).collect();
    assert_eq!(
        biased,
        vec![(ids[1], vec!["input_noise_bias".to_string()]), (ids[2], vec!["heading_offset_held".to_string()])]
    );
    // Drift flags consider the rows as usual, each marked: its change may
    // be the bias.
    assert!(h.drift.iter().any(|d| d.from_id == ids[1] && d.to_id == ids[2] && d.parameter == "c_e"), "{:?}", h.drift);
    assert!(!h.drift.is_empty() && h.drift.iter().all(|d| d.biased), "{:?}", h.drift);
    let text = h.to_string();
    assert_eq!(text.matches(crate::BIASED_NOTE).count(), h.drift.len(), "{text}");
    let named = format!(
        "not pooled, the verdict names a bias beyond its σ: row {} (input_noise_bias), row {} (heading_offset_held)",
        ids[1], ids[2]
    );
    assert!(text.contains(&named), "{text}");
    let json = serde_json::to_value(p).expect("json");
    assert_eq!(json["biased"][0], serde_json::json!({"id": ids[1], "reasons": ["input_noise_bias"]}));
    // The biased rows alone: nothing pooled, and the text says why.
    let only = db.vehicle("van", Some(&ids[1..])).expect("history");
    assert!(only.pooled.is_none());
    assert!(only.to_string().contains("nothing pooled; not pooled, the verdict names a bias"), "{only}");
    // A kind is one name: a comma would split it.
    let bad = CalibrationRecord { reasons: Some(vec!["a,b".into()]), ..record("van", "z", 1.95, 1e-3) };
    assert!(db.record(&bad).expect_err("refused").to_string().contains("reasons"));
}

/// `follow` does not start from a row whose verdict names a bias beyond
/// its σ: it starts from the most recent row without one and its start
/// line names the rows passed over.
#[test]
fn follow_does_not_start_from_a_biased_row() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
    let eiv = CalibrationRecord { reasons: Some(Vec::new()), ..record("van", "a", 1.950, 1e-3) };
    let gn = CalibrationRecord {
        method: "batch-gn".into(),
        verdict: Some("doubtful".into()),
        reasons: Some(vec!["input_noise_bias".into()]),
        ..record("van", "a", 1.960, 1e-4)
    };
    let (Recorded::New(first), Recorded::New(second)) = (db.record(&eiv).expect("eiv"), db.record(&gn).expect("gn"))
    else {
        panic!("not new");
    };
    let csv = dir.path().join("d.csv");
    noise_free_drive(1.0, 3).write_csv(&csv).expect("csv");
    let mut start = None;
    follow(&mut db, "van", std::slice::from_ref(&csv), &FollowOptions::default(), |e| {
        if let FollowEvent::Start { theta, origin } = e {
            start = Some((theta, origin));
        }
        Ok::<(), Error>(())
    })
    .expect("follow");
    let (theta, origin) = start.expect("a start");
    assert_eq!(theta.c_e.to_bits(), 1.950f64.to_bits());
    assert_eq!(
        origin,
        format!(
            "history row {first}; not started from, the verdict names a bias beyond its σ: row {second} (input_noise_bias)"
        )
    );
}

/// A file of schema version 3 is migrated on opening (and read from a
/// migrated copy by `open_read_only`): its rows' reasons are not known
/// (`NULL`), so they are pooled as before.
#[test]
fn a_version_three_file_is_migrated_and_pooled_as_before() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("h.sqlite");
    let conn = Connection::open(&path).expect("open");
    for sql in &schema::MIGRATIONS[..3] {
        conn.execute_batch(sql).expect("migration");
    }
    conn.pragma_update(None, "user_version", 3).expect("pragma");
    for (fp, method, c_e) in [("a", "eiv", 1.950), ("a", "batch-gn", 1.960), ("b", "batch-gn", 1.962)] {
        conn.execute(
            "INSERT INTO calibrations (vehicle, recorded_at, fingerprint, sources, t_start_s, t_end_s, method, \
             c_e, c_d, t_r, d, sigma_c_e, sigma_c_d, sigma_t_r, sigma_d, verdict, odocal_version, held, \
             unobservable) VALUES ('van', '2026-01-01T00:00:00.000Z', ?1, '[]', 0, 1, ?2, ?3, 0, 1.5, 0, 1e-3, \
             1e-4, 1e-2, 1e-4, 'doubtful', '0.3.0', '', '')",
            params![fp, method, c_e],
        )
        .expect("row");
    }
    drop(conn);
    let read = History::open_read_only(&path).expect("read");
    let before = read.vehicle("van", None).expect("history");
    drop(read);
    let db = History::open(&path).expect("migrate");
    assert_eq!(db.schema_version, schema::SCHEMA_VERSION);
    let h = db.vehicle("van", None).expect("history");
    assert_eq!(before, h);
    assert!(h.rows.iter().all(|r| r.record.reasons.is_none()), "not known");
    let p = h.pooled.as_ref().expect("pooled");
    assert!(p.biased.is_empty());
    assert_eq!((p.rows, p.drives), (2, 2), "{p:?}");
    assert!((p.mean.c_e - 1.961).abs() < 1e-12, "{p:?}");
}

/// A hand-edited row whose numeric column holds text is named by the file,
/// the table, the row (its id, vehicle and drive) and the column, with
/// what to do; in `calibrations` and in `decisions`.
#[test]
fn a_cell_that_does_not_read_names_its_row_and_column() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("h.sqlite");
    let mut db = History::open(&path).expect("open");
    db.record(&record("van", "fp-a", 1.95, 1e-4)).expect("a");
    let Recorded::New(id) = db.record(&record("van", "0123456789abcdef", 1.96, 1e-4)).expect("b") else {
        panic!("a new row")
    };
    let conn = Connection::open(&path).expect("open with rusqlite");
    conn.execute("UPDATE calibrations SET c_e = 'abc' WHERE id = ?1", params![id]).expect("edit");
    let e = db.vehicle("van", None).expect_err("text in c_e").to_string();
    let path_text = path.display().to_string();
    for part in [
        path_text.as_str(),
        &format!("row {id} of table calibrations (vehicle 'van', drive 0123456789ab…)"),
        "column c_e holds the text 'abc', where a number is expected",
        &format!("DELETE FROM calibrations WHERE id = {id}"),
    ] {
        assert!(e.contains(part), "{part:?} not in: {e}");
    }
    assert!(!e.contains("index"), "{e}");
    // `follow` reads the rows for its start: the same error.
    let drive = dir.path().join("d.csv");
    std::fs::write(&drive, "t\n").expect("write");
    let f = crate::follow(&mut db, "van", &[drive], &FollowOptions::default(), |_| Ok::<(), Error>(()));
    assert_eq!(f.expect_err("the bad row").to_string(), e);
    // Another vehicle's rows still read.
    assert!(db.vehicle("bus", None).is_ok());

    conn.execute("UPDATE calibrations SET c_e = 1.95 WHERE id = ?1", params![id]).expect("mend");
    let decision = DecisionRow {
        id: 0,
        decided_at: String::new(),
        odocal_version: String::new(),
        vehicle: "van".into(),
        fingerprint: "fp-c".into(),
        source: "c.csv".into(),
        source_digest: None,
        t_start_s: None,
        clock_start_s: None,
        drive_time_s: 60.0,
        decision: "held".into(),
        reasons: vec![],
        theta: theta(1.95),
        sigma: None,
    };
    let did = db.record_followed(&decision, None).expect("decision").expect("logged");
    conn.execute("UPDATE decisions SET drive_time_s = 'soon' WHERE id = ?1", params![did]).expect("edit");
    let e = db.vehicle("van", None).expect_err("text in drive_time_s").to_string();
    assert!(
        e.contains(&format!("row {did} of table decisions (vehicle 'van', drive fp-c): column drive_time_s")),
        "{e}"
    );
}
