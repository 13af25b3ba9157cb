//! Errors and notices that name the real cause: header stamps that are not
//! valid ROS times or step back, a control character in a CSV header, a
//! CSV stream cut short, a manifest key the chosen signal does not use, and
//! the importer's warnings in the JSON reports of calibrate and validate.

use std::path::Path;

use crate::common::{canonical_manifest, odocal, simulated_drive, stderr, stdout};
use crate::hostile::mcap_file;

fn s(p: &Path) -> &str {
    p.to_str().expect("utf8")
}

/// A little-endian CDR `JointState` stamped `sec.nanosec`, joints `l`, `r`
/// at angle `angle` (rad), no velocities or efforts.
fn joint_state(sec: i32, nanosec: u32, angle: f64) -> Vec<u8> {
    let mut b = vec![0, 1, 0, 0];
    b.extend(sec.to_le_bytes());
    b.extend(nanosec.to_le_bytes());
    b.extend(1u32.to_le_bytes());
    b.extend([0, 0, 0, 0]); // frame_id "" and padding
    b.extend(2u32.to_le_bytes());
    for name in [b"l\0\0\0", b"r\0\0\0"] {
        b.extend(2u32.to_le_bytes());
        b.extend(name);
    }
    b.extend(2u32.to_le_bytes()); // at offset 36 of the body: the angles are 8-aligned
    b.extend(angle.to_le_bytes());
    b.extend(angle.to_le_bytes());
    b.extend([0; 8]); // no velocities, no efforts
    b
}

/// Imports a manifest whose wheels are the bag `stamps` make (pose from
/// the shipped slice) and returns stderr, asserting exit 1.
fn import_wheels(dir: &Path, stamps: &[(i32, u32)]) -> String {
    let messages: Vec<Vec<u8>> =
        stamps.iter().enumerate().map(|(i, &(sec, ns))| joint_state(sec, ns, i as f64 * 0.1)).collect();
    std::fs::write(dir.join("w.mcap"), mcap_file(None, &messages)).expect("write");
    let slice = Path::new(env!("CARGO_MANIFEST_DIR")).join("../odocal/tests/data/psu-mapping-van/drive-slice.mcap");
    let manifest = format!(
        "[streams.wheels]\nformat = \"mcap\"\nfile = \"w.mcap\"\ntopic = \"/j\"\n\n[streams.pose]\nformat = \"mcap\"\n\
         file = \"{}\"\ntopic = \"/localization/pose_with_covariance\"\n\n[wheels]\nstream = \"wheels\"\n\
         signal = \"rad_cumulative\"\nrear_left = {{ column = \"position.l\" }}\nrear_right = {{ column = \"position.r\" }}\n\n\
         [pose]\nstream = \"pose\"\nposition = {{ kind = \"local\", x = \"x\", y = \"y\" }}\n",
        slice.display()
    );
    let m = dir.join("m.toml");
    std::fs::write(&m, manifest).expect("write");
    let o = odocal(&["import", s(&m), "--out", s(&dir.join("o.csv"))]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    e
}

#[test]
fn a_stamp_with_nanosec_of_a_second_or_more_is_named() {
    let dir = tempfile::tempdir().expect("tmp");
    let e = import_wheels(dir.path(), &[(100, 0), (100, 2_000_000_000), (101, 0)]);
    assert!(
        e.contains(
            "topic '/j': message 1 (log time 1.010000000 s) has header.stamp.nanosec = 2000000000, not below \
                    10^9 (sec = 100)"
        ),
        "{e}"
    );
    // The advice names the log time, not a rate (the message without the
    // temporary directory's random name, which may hold any letters).
    let advice = e.replace(&dir.path().display().to_string(), "");
    assert!(advice.contains("time = \"log\"") && !advice.contains("Hz"), "{e}");
}

#[test]
fn a_header_clock_stepping_back_is_named_with_the_step() {
    let dir = tempfile::tempdir().expect("tmp");
    let e = import_wheels(dir.path(), &[(100, 0), (100, 500_000_000), (90, 0), (90, 500_000_000)]);
    assert!(
        e.contains(
            "topic '/j': the header clock steps back 10.5 s at message 2 (log time 1.020000000 s): its stamp \
                    90 s is before message 1's 100.5 s"
        ),
        "{e}"
    );
    assert!(!e.contains("m/s"), "{e}");
}

#[test]
fn a_nul_in_a_csv_header_is_named_as_the_cause() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let text = std::fs::read_to_string(&d).expect("drive");
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, text.replacen("px", "p\0x", 1)).expect("write");
    let o = odocal(&["validate", s(&bad), "--theta", "2,0,1.6,0"]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains(&format!("column 2 of the header of {} ('p\\u{{0}}x') contains a NUL byte", s(&bad))), "{e}");
    assert!(!e.contains("missing column"), "{e}");
    // The same in a manifest's CSV stream.
    std::fs::write(dir.path().join("z.csv"), text.replacen("px", "p\0x", 1)).expect("write");
    let m = dir.path().join("m.toml");
    std::fs::write(&m, canonical_manifest("z.csv", "")).expect("write");
    let o = odocal(&["import", s(&m), "--out", s(&dir.path().join("o.csv"))]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("column 2 of the header of") && e.contains("z.csv ('p\\u{0}x') contains a NUL byte"), "{e}");
    assert!(!e.contains("not found"), "{e}");
}

/// A θ argument naming an existing file without a parameter file's
/// extension (a YAML file named `.txt`, a drive CSV) says so, not that it
/// is not four numbers.
#[test]
fn a_theta_file_without_a_parameter_extension_is_named() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "1"]);
    let p = dir.path().join("p.txt");
    std::fs::write(&p, "c_e: 2.0\nc_d: 0.0\nt_r: 1.6\nd: 0.0\n").expect("write");
    for theta in [s(&p), d.as_str()] {
        let o = odocal(&["validate", &d, "--theta", theta]);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{e}");
        assert!(e.contains("is a file, but its name does not end in .yaml, .yml or .json"), "{e}");
        assert!(!e.contains("comma-separated"), "{e}");
    }
    // Text that names no file is read as four numbers.
    let e = stderr(&odocal(&["validate", &d, "--theta", "p.txt"]));
    assert!(e.contains("expected 4 comma-separated values"), "{e}");
}

/// A manifest whose CSV stream lacks its final newline: the importer warns,
/// and calibrate and validate show the warning on stderr and in the JSON
/// report's `import_warnings`. A key the wheel signal does not use is
/// noticed the same way.
#[test]
fn import_warnings_reach_the_json_reports() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    let text = std::fs::read_to_string(&d).expect("drive");
    std::fs::write(dir.path().join("z.csv"), text.trim_end()).expect("write");
    let m = dir.path().join("m.toml");
    let manifest = canonical_manifest("z.csv", "")
        .replace("signal = \"rev_per_s\"", "signal = \"rev_per_s\"\nticks_per_rev = 100");
    std::fs::write(&m, manifest).expect("write");
    let tail = "the last line, has no newline at its end";
    let unused = "wheels.ticks_per_rev = 100 does not apply to signal = \"rev_per_s\" (only to ticks_cumulative and \
                  ticks_raw): ignored";
    for args in [
        vec!["calibrate", s(&m), "--json", "-"],
        vec!["validate", s(&m), "--theta", "2,0,1.6,0", "--no-drive-fit", "--json", "-"],
    ] {
        let o = odocal(&args);
        let e = stderr(&o);
        assert!(o.status.success(), "{args:?}: {e}");
        assert!(e.contains(tail) && e.contains(unused), "{e}");
        let v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("json");
        let w: Vec<&str> =
            v["import_warnings"].as_array().expect("import_warnings").iter().filter_map(|w| w.as_str()).collect();
        assert!(w.iter().any(|w| w.contains(tail) && w.contains("streams.d")), "{w:?}");
        assert!(w.iter().any(|w| w.contains(unused) && w.starts_with(s(&m))), "{w:?}");
    }
    // The HTML report lists them with the calibration's warnings.
    let o = odocal(&["calibrate", s(&m), "--report", "-"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let html = stdout(&o);
    let warnings = &html[html.find("id=\"warnings\"").expect("warnings section")..];
    assert!(warnings.contains(tail) && warnings.contains("streams.d"), "{warnings}");
    assert!(warnings.contains("wheels.ticks_per_rev = 100 does not apply"), "{warnings}");
    // `import` sends them to stderr too: stdout holds the report alone.
    let o = odocal(&["import", s(&m), "--out", s(&dir.path().join("o.csv"))]);
    let (out, e) = (stdout(&o), stderr(&o));
    assert!(o.status.success(), "{e}");
    assert!(out.contains("import of") && !out.contains("warning"), "{out}");
    assert!(e.contains(tail), "{e}");
    assert!(e.lines().any(|l| l.starts_with("warning: ") && l.contains(unused)), "{e}");
}
