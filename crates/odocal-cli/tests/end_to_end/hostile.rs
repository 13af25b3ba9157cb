//! Hostile inputs end in a clear error, never a hang, an unbounded
//! allocation or raw escape sequences on the terminal: devices and FIFOs
//! where a file is expected, a YAML alias bomb, counts of a billion, control
//! characters in names, and a reader of stdout that goes away.

use std::io::Read;
use std::path::Path;
use std::process::{Command, Stdio};

use crate::common::{odocal, simulated_drive, stderr};

fn s(p: &Path) -> &str {
    p.to_str().expect("utf8")
}

/// Runs odocal under a 1 GB address-space limit (`ulimit -v`): it must
/// exit with an error (1 or 2) whose message holds each of `needles`.
fn refused_within_1gb(args: &[&str], needles: &[&str]) {
    let quoted: Vec<String> = args.iter().map(|a| format!("'{}'", a.replace('\'', "'\\''"))).collect();
    let script = format!("ulimit -v 1000000; exec '{}' {} --quiet", env!("CARGO_BIN_EXE_odocal"), quoted.join(" "));
    let o = Command::new("bash").arg("-c").arg(&script).output().expect("bash");
    let e = stderr(&o);
    assert!(matches!(o.status.code(), Some(1 | 2)), "{args:?}: {:?} {e}", o.status);
    for n in needles {
        assert!(e.contains(n), "{args:?}: '{n}' not in: {e}");
    }
}

#[test]
fn devices_and_fifos_are_refused_by_name() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let link = |name: &str| {
        let p = dir.path().join(name);
        std::os::unix::fs::symlink("/dev/zero", &p).expect("symlink");
        p.to_str().expect("utf8").to_owned()
    };
    let out = dir.path().join("o.csv");
    refused_within_1gb(&["validate", &link("z.csv"), "--theta", "2,0,1.6,0"], &["a character device", "drive CSV"]);
    refused_within_1gb(&["import", &link("z.toml"), "--out", s(&out)], &["a character device", "a manifest"]);
    refused_within_1gb(&["validate", &d, "--theta", &link("z.yaml")], &["a character device", "parameter file"]);
    refused_within_1gb(&["calibrate", &d, "--noise-model", &link("n.toml")], &["a character device", "noise model"]);
    let fifo = dir.path().join("f.csv");
    assert!(Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
    refused_within_1gb(&["validate", s(&fifo), "--theta", "2,0,1.6,0"], &["a FIFO (named pipe)"]);
}

#[test]
fn a_yaml_alias_bomb_is_refused_before_it_expands() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let mut yaml = String::from("a0: &a0 [\"lol\",\"lol\",\"lol\",\"lol\",\"lol\",\"lol\",\"lol\",\"lol\",\"lol\"]\n");
    for k in 1..9 {
        let p = k - 1;
        yaml.push_str(&format!("a{k}: &a{k} [*a{p},*a{p},*a{p},*a{p},*a{p},*a{p},*a{p},*a{p},*a{p}]\n"));
    }
    let bomb = dir.path().join("bomb.yaml");
    std::fs::write(&bomb, yaml).expect("write");
    refused_within_1gb(&["validate", &d, "--theta", s(&bomb)], &["bomb.yaml", "a YAML alias"]);
}

#[test]
fn counts_and_threads_above_their_ceilings_are_refused_before_allocating() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let huge = "1000000000";
    refused_within_1gb(&["calibrate", &d, "--bootstrap", huge], &["--bootstrap", "above its ceiling of 100000"]);
    refused_within_1gb(&["calibrate", &d, "--correct-bias", huge], &["--correct-bias", "ceiling"]);
    refused_within_1gb(&["calibrate", &d, "--method", "three-step", "--picks", huge], &["--picks", "ceiling"]);
    refused_within_1gb(&["calibrate", &d, "--method", "three-step", "--batches", huge], &["--batches", "ceiling"]);
    refused_within_1gb(
        &["--threads", "100000", "validate", &d, "--theta", "2,0,1.6,0"],
        &["--threads 100000", "ceiling"],
    );
}

#[test]
fn control_characters_in_names_are_escaped_when_echoed() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let text = std::fs::read_to_string(&d).expect("drive");
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, text.replacen("px", "p\u{1b}[2Jx", 1)).expect("write");
    let o = odocal(&["validate", s(&bad), "--theta", "2,0,1.6,0"]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(!e.contains('\u{1b}') && e.contains("p\\u{1b}[2Jx"), "{e}");
}

#[test]
fn a_closed_stdout_ends_the_command_quietly() {
    let m = Path::new(env!("CARGO_MANIFEST_DIR")).join("../odocal/tests/data/psu-mapping-van/manifest.toml");
    let mut child = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(["import", s(&m), "--out", "-", "--quiet"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    let mut first = [0u8; 16];
    child.stdout.take().expect("stdout").read_exact(&mut first).expect("read");
    let o = child.wait_with_output().expect("wait");
    let e = stderr(&o);
    assert!(matches!(o.status.code(), Some(0 | 141)), "{:?}: {e}", o.status);
    assert!(!e.contains("panicked"), "{e}");
}

#[test]
fn stamps_that_never_advance_are_named() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let text = std::fs::read_to_string(&d).expect("drive");
    let mut lines = text.lines();
    let mut out = format!("{},stamp\n", lines.next().expect("header"));
    for l in lines {
        out.push_str(&format!("{l},0\n"));
    }
    std::fs::write(dir.path().join("z.csv"), out).expect("write");
    let m = dir.path().join("m.toml");
    let manifest =
        crate::common::canonical_manifest("z.csv", "").replace("time_column = \"t\"", "time_column = \"stamp\"");
    std::fs::write(&m, manifest).expect("write");
    let o = odocal(&["import", s(&m), "--out", s(&dir.path().join("x.csv"))]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("streams.d: the time column 'stamp' holds one time (0 s) in all"), "{e}");
}
