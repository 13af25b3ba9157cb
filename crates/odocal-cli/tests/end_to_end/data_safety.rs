//! The user's data are never lost: an output onto an input (or onto
//! another output) is refused before any work, every output is written
//! atomically, a cut-off CSV is not read as a drive, the same drive (or a
//! part of it) is not counted twice and a simulator sidecar is the truth of
//! its own drive only.

use std::path::{Path, PathBuf};

use crate::common::{odocal, simulated_drive, stderr, stdout};

/// A copy of the van slice (manifest, stream files, bag) in a fresh folder.
fn van_copy(dir: &Path) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../odocal/tests/data/psu-mapping-van");
    let dst = dir.join("van");
    std::fs::create_dir(&dst).expect("mkdir");
    for e in std::fs::read_dir(&src).expect("van slice") {
        let e = e.expect("entry");
        std::fs::copy(e.path(), dst.join(e.file_name())).expect("copy");
    }
    dst
}

fn read(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// Runs odocal, asserting it fails with a message containing each of `needles`.
fn refused(args: &[&str], needles: &[&str]) {
    let o = odocal(args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{args:?} was not refused: {e}");
    for n in needles {
        assert!(e.contains(n), "{args:?}: '{n}' not in: {e}");
    }
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf8")
}

#[test]
fn import_out_onto_its_manifest_or_a_stream_file_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let van = van_copy(dir.path());
    let (manifest, stream) = (van.join("manifest.toml"), van.join("encoders.csv"));
    let before = (read(&manifest), read(&stream));
    refused(&["import", s(&manifest), "--out", s(&manifest)], &["--out", "is also the manifest being imported"]);
    refused(
        &["import", s(&manifest), "--out", &format!("{}/./encoders.csv", van.display())],
        &["--out", "is also stream 'encoders' of the manifest"],
    );
    refused(&["import", s(&manifest), "--out", "x.csv", "--json", s(&stream)], &["--json", "stream 'encoders'"]);
    assert_eq!((read(&manifest), read(&stream)), before, "an input was changed");
}

#[test]
fn import_out_and_json_onto_one_file_are_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let van = van_copy(dir.path());
    let out = dir.path().join("x.csv");
    refused(
        &["import", s(&van.join("manifest.toml")), "--out", s(&out), "--json", s(&out)],
        &["--json", "is also --out"],
    );
    assert!(!out.exists());
}

#[test]
fn simulate_out_onto_its_own_sidecar_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("x.json");
    refused(&["simulate", "--length-km", "1", "--out", s(&out)], &["--out", "give --out a name ending in .csv"]);
    assert!(!out.exists());
    refused(&["simulate", "--out", "-"], &["--out -", "sidecar"]);
}

/// The sidecar is written beside `--out` under its name with .json: a file
/// there that is not a simulator sidecar (a calibration's report, say) is
/// left alone and the run (`simulate`, `demo`) refused before any work; an older sidecar is
/// replaced, as its CSV is.
#[test]
fn simulate_leaves_a_json_beside_out_that_is_no_sidecar() {
    let dir = tempfile::tempdir().expect("tmp");
    let (out, side) = (dir.path().join("run.csv"), dir.path().join("run.json"));
    std::fs::write(&side, "{\"validation\": {\"mean_position_error_m\": 1.0}}\n").expect("write");
    let before = read(&side);
    refused(&["simulate", "--length-km", "1", "--out", s(&out)], &["run.json", "is not a simulator sidecar"]);
    refused(&["demo", "--length-km", "1", "--out", s(&out)], &["run.json", "beside --out"]);
    assert_eq!(read(&side), before, "the JSON was changed");
    assert!(!out.exists(), "the CSV was written though the run was refused");
    std::fs::remove_file(&side).expect("remove");
    for seed in ["1", "2"] {
        let o = odocal(&["simulate", "--length-km", "1", "--seed", seed, "--out", s(&out)]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let truth: serde_json::Value = serde_json::from_slice(&read(&side)).expect("sidecar");
    assert_eq!(truth["settings"]["seed"], serde_json::json!(2), "the second run's sidecar");
}

#[test]
fn calibrate_and_validate_outputs_onto_their_inputs_are_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "in.csv", &["--length-km", "2"]);
    let (csv, side) = (PathBuf::from(&d), dir.path().join("in.json"));
    let before = (read(&csv), read(&side));
    let alias = format!("{}/./in.csv", dir.path().display());
    for flag in ["--report", "--json"] {
        refused(
            &["calibrate", &d, "--method", "batch-gn", flag, &alias],
            &[flag, "is also the drive being calibrated"],
        );
    }
    refused(
        &["calibrate", &d, "--method", "batch-gn", "--params-out", s(&side)],
        &["--params-out", "is also the simulator sidecar of"],
    );
    refused(
        &["validate", &d, "--theta", "1.95,-0.002,1.53,0.0008", "--json", &d],
        &["--json", "is also the drive being validated"],
    );
    refused(&["compensate", &d, "--theta", "1.95,-0.002,1.53,0.0008", "--out", &d], &["--out", "is also"]);
    assert_eq!((read(&csv), read(&side)), before, "an input was changed");
}

#[test]
fn calibrate_outputs_onto_a_manifests_stream_file_are_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let van = van_copy(dir.path());
    let stream = van.join("pose_rear_antenna_mid.csv");
    let before = read(&stream);
    refused(
        &["calibrate", s(&van.join("manifest.toml")), "--json", s(&stream)],
        &["--json", "is also stream 'pose' of the manifest"],
    );
    assert_eq!(read(&stream), before);
}

#[test]
fn experiment_into_a_folder_with_a_report_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let report = dir.path().join("report.md");
    std::fs::write(&report, "my notes\n").expect("seed");
    refused(&["experiment", "--length-km", "2", "--out", s(dir.path())], &["holds an experiment already", "--force"]);
    assert_eq!(read(&report), b"my notes\n");
    refused(&["experiment", "--out", "-"], &["--out -"]);
}

/// `experiment --out` naming a file is refused as a file, and a run that
/// fails before it has results (here a drive that cannot be read) leaves no
/// folder behind.
#[test]
fn experiment_out_is_a_folder_and_a_failed_run_makes_none() {
    let dir = tempfile::tempdir().expect("tmp");
    let file = dir.path().join("sim.csv");
    std::fs::write(&file, "t\n").expect("seed");
    refused(&["experiment", "--out", s(&file)], &["is a file, not a folder"]);
    assert_eq!(read(&file), b"t\n");
    let out = dir.path().join("new");
    let missing = dir.path().join("missing.csv");
    refused(&["experiment", "--drive", s(&missing), "--out", s(&out)], &["missing.csv"]);
    assert!(!out.exists(), "a failed experiment left {}", out.display());
}

/// An interrupted `simulate` leaves the previous drive at the final path
/// (or, when it finished first, the whole new one), never a part of a drive.
#[cfg(unix)]
#[test]
fn an_interrupted_simulate_leaves_the_previous_drive() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("d.csv");
    let old = b"t,px,py,psi,n_rl,n_rr,beta,a_y\n0,0,0,0,5,5,0,0\n0.025,0.25,0,0,5,5,0,0\n";
    std::fs::write(&out, old).expect("seed");
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(["simulate", "--length-km", "60", "--quiet", "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("spawn");
    // Interrupt while the CSV is being written (its temporary file exists).
    let writing = || {
        std::fs::read_dir(dir.path())
            .expect("ls")
            .any(|e| e.expect("entry").file_name().to_string_lossy().ends_with(".tmp"))
    };
    let started = std::time::Instant::now();
    let mut interrupted = false;
    while started.elapsed().as_secs() < 300 {
        if child.try_wait().expect("wait").is_some() {
            break;
        }
        if writing() {
            std::thread::sleep(std::time::Duration::from_millis(50));
            let kill = std::process::Command::new("kill").args(["-INT", &child.id().to_string()]).status();
            interrupted = kill.expect("kill").success();
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let status = child.wait().expect("wait");
    let now = read(&out);
    eprintln!("interrupted while writing: {interrupted}, exit status {status}");
    if interrupted && !status.success() {
        assert_eq!(status.code(), Some(130), "{status}");
        assert_eq!(now, old, "an interrupted write changed the final path");
        assert!(!writing(), "a temporary file was left behind");
    } else {
        assert!(status.success());
        let o = odocal(&["validate", s(&out), "--theta", "1.95,-0.002,1.53,0.0008"]);
        assert!(o.status.success(), "the finished drive does not read: {}", stderr(&o));
    }
}

#[test]
fn a_cut_off_csv_is_an_error_and_a_missing_last_newline_a_warning() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let text = std::fs::read_to_string(&d).expect("csv");
    let theta = "1.95,-0.002,1.53,0.0008";
    // Cut in the middle of the last row: a short row.
    let cut = dir.path().join("cut.csv");
    std::fs::write(&cut, &text[..text.len() - 40]).expect("write");
    let lines = text[..text.len() - 40].lines().count();
    refused(&["validate", s(&cut), "--theta", theta], &["cut.csv", &format!("line {lines}"), "the last row is short"]);
    // Cut in the last number of the last row: read, with a warning.
    let open = dir.path().join("open.csv");
    let whole = text.trim_end();
    let last_field = whole.rsplit(',').next().unwrap_or("");
    let keep = whole.len() - usize::from(last_field.len() > 1);
    std::fs::write(&open, &whole[..keep]).expect("write");
    let o = odocal(&["validate", s(&open), "--theta", theta]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("has no newline at its end"), "{}", stderr(&o));
    assert!(!stderr(&odocal(&["validate", &d, "--theta", theta])).contains("newline"));
}

#[test]
fn the_same_drive_twice_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    let copy = dir.path().join("copy.csv");
    std::fs::copy(&d, &copy).expect("copy");
    refused(
        &["calibrate", &d, s(&copy), "--method", "batch-gn"],
        &["drive 2 (", "copy.csv) is the same drive as drive 1 (", "give each drive once"],
    );
    refused(
        &["calibrate", &d, "--method", "batch-gn", "--validate-on", s(&copy)],
        &["the --validate-on drive", "is the same drive as", "no validation"],
    );
}

#[test]
fn a_manifest_and_the_csv_it_imports_to_have_one_fingerprint() {
    let dir = tempfile::tempdir().expect("tmp");
    let van = van_copy(dir.path());
    let manifest = van.join("manifest.toml");
    let csv = dir.path().join("van.csv");
    let o = odocal(&["import", s(&manifest), "--out", s(&csv), "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let import: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let fp = import["fingerprint"].as_str().expect("fingerprint").to_string();
    assert_eq!(fp.len(), 64);
    let o = odocal(&["validate", s(&csv), "--theta", "1.95,0,1.6,0", "--json", "-"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(v["drives"][0]["fingerprint"], fp.as_str(), "the CSV and the manifest differ");
    refused(&["calibrate", s(&csv), s(&manifest), "--method", "batch-gn"], &["is the same drive as"]);
}

/// The same samples read another way have another fingerprint (a
/// manifest over the drive CSV averages the wheel speeds over its output
/// interval and drops the last sample; another CSV counts time from
/// another origin, orders its columns otherwise and rounds the pose to
/// 0.1 mm): still not held-out evidence, nor a second drive.
#[test]
fn the_same_samples_imported_another_way_are_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--seed", "4", "--length-km", "2", "--noise", "off"]);
    let manifest = dir.path().join("d.toml");
    let toml = "[output]\nrate_hz = 40.0\nclock_offset = 0.0\nmin_part_s = 10.0\n\n\
        [streams.log]\nfile = \"d.csv\"\ntime_column = \"t\"\n\n\
        [wheels]\nstream = \"log\"\nsignal = \"rev_per_s\"\n\
        rear_left = { column = \"n_rl\" }\nrear_right = { column = \"n_rr\" }\n\n\
        [pose]\nstream = \"log\"\n\n[pose.position]\nkind = \"local\"\nx = \"px\"\ny = \"py\"\n\n\
        [pose.heading]\ncolumn = \"psi\"\nconvention = \"enu\"\nunit = \"rad\"\n\n\
        [lateral_acceleration]\nsource = \"imu\"\nstream = \"log\"\ncolumn = \"a_y\"\n\n\
        [sideslip]\nsource = \"zero\"\n";
    std::fs::write(&manifest, toml).expect("manifest");
    // Columns reversed, an extra one, time from another origin, the pose rounded.
    let text = std::fs::read_to_string(&d).expect("drive");
    let mut rows = text.lines().map(|l| l.split(',').collect::<Vec<_>>());
    let header = rows.next().expect("header");
    let col = |name: &str| header.iter().position(|h| *h == name).expect("column");
    let keep = ["t", "px", "py", "psi", "n_rl", "n_rr", "beta", "a_y"].map(col);
    let mut out = String::from("note,a_y,beta,n_rr,n_rl,psi,py,px,t\n");
    for r in rows {
        let v = keep.map(|k| r[k].parse::<f64>().expect("number"));
        let (t, pose) = (v[0] + 1000.0, [v[1], v[2], v[3]].map(|x| format!("{x:.4}")));
        out.push_str(&format!("7,{},{},{},{},{},{},{},{t}\n", v[7], v[6], v[5], v[4], pose[2], pose[1], pose[0]));
    }
    let other = dir.path().join("other.csv");
    std::fs::write(&other, out).expect("write");
    let prints: Vec<String> = [d.as_str(), s(&manifest), s(&other)]
        .iter()
        .map(|p| {
            let o = odocal(&["validate", p, "--theta", "1.95,0,1.6,0", "--no-drive-fit", "--json", "-"]);
            assert!(o.status.success(), "{}", stderr(&o));
            let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
            v["drives"][0]["fingerprint"].as_str().expect("fingerprint").to_string()
        })
        .collect();
    assert!(prints[0] != prints[1] && prints[0] != prints[2], "{prints:?}");
    for copy in [s(&manifest), s(&other)] {
        refused(
            &["calibrate", &d, "--method", "batch-gn", "--validate-on", copy],
            &[
                "the --validate-on drive",
                "holds the same samples as",
                "the reference path within 1 mm",
                "no validation",
            ],
        );
        refused(
            &["calibrate", &d, copy, "--method", "batch-gn"],
            &["drive 2 (", "holds the same samples as drive 1 ("],
        );
    }
    // Another drive is not: the check does not refuse what differs.
    let e = simulated_drive(dir.path(), "e.csv", &["--seed", "5", "--length-km", "2", "--noise", "off"]);
    let o = odocal(&["calibrate", &d, "--method", "batch-gn", "--validate-on", &e]);
    assert!(o.status.success(), "{}", stderr(&o));
}

/// A part of the calibration drive, or a copy of it at half the rate, is
/// not held-out data nor a second drive, whatever its time stamps; a
/// separate drive at another rate is not validation data either: its
/// validation segments would span another length of drive.
#[test]
fn a_part_or_a_thinned_copy_of_the_drive_is_refused_and_so_is_another_rate() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    let text = std::fs::read_to_string(&d).expect("drive");
    let lines: Vec<&str> = text.lines().collect();
    let write = |name: &str, keep: &dyn Fn(usize) -> bool| {
        let p = dir.path().join(name);
        let rows: Vec<&str> = lines.iter().enumerate().filter(|(i, _)| *i == 0 || keep(*i)).map(|(_, l)| *l).collect();
        std::fs::write(&p, rows.join("\n") + "\n").expect("write");
        p
    };
    // The first 4000 samples; every other sample (20 Hz).
    let part = write("part.csv", &|i| i <= 4000);
    let half = write("half.csv", &|i| i % 2 == 1);
    let refusal = [" shares 100 % of its samples with ", "held-out data must be a different drive"];
    for copy in [&part, &half] {
        let name = format!("the --validate-on drive {}", s(copy));
        refused(&["calibrate", &d, "--method", "batch-gn", "--validate-on", s(copy)], &[&name, &refusal[0][1..]]);
        refused(&["calibrate", &d, s(copy), "--method", "batch-gn"], &refusal);
    }
    refused(
        &["calibrate", s(&part), "--method", "batch-gn", "--validate-on", &d],
        &[&format!("{} shares 100 %", s(&part))],
    );
    // Another drive at half the rate.
    let e = simulated_drive(dir.path(), "e.csv", &["--seed", "5", "--length-km", "2"]);
    let e20 = dir.path().join("e20.csv");
    let e_text = std::fs::read_to_string(&e).expect("drive");
    let rows: Vec<&str> = e_text.lines().enumerate().filter(|(i, _)| i % 2 == 0).map(|(_, l)| l).collect();
    std::fs::write(&e20, rows.join("\n") + "\n").expect("write");
    refused(
        &["calibrate", &d, "--method", "batch-gn", "--validate-on", s(&e20)],
        &[&format!("validation drive {}: its sample time is 0.050000 s, the calibration drive's 0.025000 s", s(&e20))],
    );
}

#[test]
fn a_sidecar_is_the_truth_of_its_own_drive_only() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    let flags = ["--method", "batch-gn"];
    let own = odocal(&[&["calibrate", d.as_str()][..], &flags].concat());
    assert!(stdout(&own).contains("error against truth"), "{}", stdout(&own));
    // Another drive written over the CSV, the old sidecar left beside it.
    let other = simulated_drive(dir.path(), "other.csv", &["--length-km", "2", "--seed", "5"]);
    std::fs::copy(&other, &d).expect("copy");
    let o = odocal(&[&["calibrate", d.as_str()][..], &flags].concat());
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stdout(&o).contains("truth"), "{}", stdout(&o));
    assert!(stderr(&o).contains("d.json is not the truth of this drive"), "{}", stderr(&o));
}

#[test]
fn dash_is_stdout() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    let o = odocal(&["calibrate", &d, "--method", "batch-gn", "--report", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).starts_with("<!DOCTYPE html>"), "{}", &stdout(&o)[..100.min(stdout(&o).len())]);
    let o = odocal(&["calibrate", &d, "--method", "batch-gn", "--params-out", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("ros__parameters:") && stdout(&o).contains("fingerprint:"), "{}", stdout(&o));
    let van = van_copy(dir.path());
    let o = odocal(&["import", s(&van.join("manifest.toml")), "--out", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).starts_with("t,px,py,psi,n_rl,n_rr,beta,a_y"), "{}", &stdout(&o)[..80]);
    assert!(!Path::new("-").exists() && !dir.path().join("-").exists());
}

#[test]
fn reports_name_the_drives_fingerprints() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    let params = dir.path().join("p.yaml");
    let o = odocal(&["calibrate", &d, "--method", "batch-gn", "--params-out", s(&params), "--json", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let entry = &v["drives"][0];
    assert_eq!((entry["role"].as_str(), entry["path"].as_str()), (Some("calibration"), Some(d.as_str())));
    let fp = entry["fingerprint"].as_str().expect("fingerprint");
    let side: serde_json::Value = serde_json::from_slice(&read(&dir.path().join("d.json"))).expect("sidecar");
    assert_eq!(side["drive_fingerprint"], fp, "the sidecar records the drive's fingerprint");
    let yaml = std::fs::read_to_string(&params).expect("params");
    assert!(yaml.contains(&format!("fingerprint: \"{fp}\"")), "{yaml}");
}
