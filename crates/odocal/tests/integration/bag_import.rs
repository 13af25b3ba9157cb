//! `format = "mcap"` manifests through the importer: the shipped slice bag,
//! and the full PSU mapping-van bag against the CSV manifest that uses the
//! same clocks (`examples/psu-mapping-van/manifest-ros-time.toml`).

use odocal::{import, Manifest};
use std::path::Path;
#[cfg(feature = "mcap")]
use std::path::PathBuf;

#[cfg(feature = "mcap")]
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

#[cfg(feature = "mcap")]
fn load(rel: &str) -> Manifest {
    let p = root().join(rel);
    Manifest::from_path(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// The bag and the CSVs hold the same numbers on the same clock, so the two
/// imports must give the same drive.
///
/// Differences that remain, and why they are far inside the tolerances:
/// - wheel rotation: the bag stores `ticks × (2π / 40360)` rad and the import
///   divides by 2π, where the CSV path divides the ticks by 40,360: two
///   roundings at ~6,000 revolutions, ~1e-12 rev, which the rate over one
///   25 ms step turns into < 1e-10 rev/s (measured 7e-11);
/// - heading: the bag stores yaw as a quaternion, decoded with `atan2`:
///   ~4e-16 rad;
/// - positions are stored bit-exact (MCAP.md), so they agree exactly; the
///   times are the same decimal `ros_time_s` parsed to the nearest f64 in
///   both readers, so the de-jittering, clock offset and the parts agree.
#[cfg(feature = "mcap")]
#[test]
fn full_bag_imports_as_the_ros_time_csv_manifest() {
    let from_bag = import(&load("examples/psu-mapping-van/manifest-mcap.toml")).expect("bag import");
    let from_csv = import(&load("examples/psu-mapping-van/manifest-ros-time.toml")).expect("CSV import");
    let (a, b) = (&from_bag.0, &from_csv.0);
    assert_eq!(a.parts(), b.parts(), "parts");
    assert_eq!(a.len(), b.len());
    assert!(a.parts().len() >= 5, "the van drive has several parts, found {}", a.parts().len());
    assert_eq!(
        from_bag.1.clock_offset.applied_s.to_bits(),
        from_csv.1.clock_offset.applied_s.to_bits(),
        "clock offset"
    );
    let max_diff = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
    assert!(a.t().iter().zip(b.t()).all(|(p, q)| p.to_bits() == q.to_bits()), "times differ");
    let pos = max_diff(&a.measured().px, &b.measured().px).max(max_diff(&a.measured().py, &b.measured().py));
    assert!(pos <= 1e-3, "positions differ by {pos} m");
    let wheels = max_diff(&a.measured().n_rl, &b.measured().n_rl).max(max_diff(&a.measured().n_rr, &b.measured().n_rr));
    assert!(wheels <= 1e-6, "wheel rotations differ by {wheels} rev/s");
    let psi = max_diff(&a.measured().psi, &b.measured().psi);
    assert!(psi <= 1e-9, "headings differ by {psi} rad");
    // Quality: the bag's covariance threshold rejects exactly the rows the
    // CSV's both_fix6 = 0 rejects.
    let gaps = |r: &odocal::ImportReport| serde_json::to_value(r).expect("JSON")["gaps"].clone();
    assert_eq!(gaps(&from_bag.1).as_array().map(Vec::len), gaps(&from_csv.1).as_array().map(Vec::len), "gaps");
}

/// The shipped 120 s slice bag imports: both wheels, the pose, its quality
/// threshold; and `time = "log"` gives the same drive (this bag's log time is
/// its header stamp).
#[cfg(feature = "mcap")]
#[test]
fn slice_bag_imports() {
    let text = r#"
[output]
min_part_s = 10.0
clock_offset = 0.0

[streams.wheels]
format = "mcap"
file = "drive-slice.mcap"
topic = "/vehicle/wheel_joint_states"
nominal_rate_hz = 100.0

[streams.pose]
format = "mcap"
file = "drive-slice.mcap"
topic = "/localization/pose_with_covariance"
time = "TIME"

[wheels]
stream = "wheels"
signal = "rad_cumulative"
rear_left = { column = "position.rear_left_wheel_joint" }
rear_right = { column = "position.rear_right_wheel_joint" }

[pose]
stream = "pose"
position = { kind = "local", x = "x", y = "y" }
heading = { column = "yaw", convention = "enu" }
quality = { column = "cov_x", max = 0.01 }
"#;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/psu-mapping-van");
    let run = |time: &str| {
        let m = Manifest::parse(&text.replace("TIME", time), &dir.join("slice-manifest.toml")).expect("manifest");
        import(&m).expect("slice import")
    };
    let header = run("header");
    let d = &header.0;
    // 120 s of bag; the first pose samples are not RTK fixed (cov_x = 100).
    let span = d.t().last().copied().unwrap_or(0.0) - d.t()[0];
    assert!(span > 60.0 && span < 120.0, "span {span} s");
    let report = serde_json::to_value(&header.1).expect("the import report as JSON");
    let gaps = report["gaps"].as_array().expect("gaps");
    assert!(!gaps.is_empty(), "the slice starts with rejected pose quality");
    let why = gaps[0]["reasons"].to_string();
    assert!(why.contains("cov_x"), "{why}");
    let moving = d.measured().n_rl.iter().filter(|n| **n > 1.0).count();
    assert!(moving > d.len() / 2, "the van drives through most of the slice ({moving} of {} samples)", d.len());
    let log = run("log");
    assert_eq!(log.0.parts(), d.parts());
    assert_eq!(log.0.measured().px, d.measured().px);
}

/// A two-stream manifest with the stream keys `wheels_keys` and the pose
/// quality table `quality`.
fn small_manifest(wheels_keys: &str, quality: &str) -> String {
    format!(
        r#"
[streams.wheels]
{wheels_keys}

[streams.pose]
file = "p.csv"
time_column = "t"

[wheels]
stream = "wheels"
signal = "rad_cumulative"
rear_left = {{ column = "l" }}
rear_right = {{ column = "r" }}

[pose]
stream = "pose"
position = {{ kind = "local", x = "x", y = "y" }}
{quality}
"#
    )
}

fn parse_err(text: &str) -> String {
    match Manifest::parse(text, Path::new("m.toml")) {
        Ok(_) => panic!("expected an error for:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn mcap_stream_keys_are_checked() {
    let mcap = "format = \"mcap\"\nfile = \"b.mcap\"\ntopic = \"/w\"";
    let ok = Manifest::parse(&small_manifest(&format!("{mcap}\ntime = \"log\""), ""), Path::new("m.toml"));
    assert!(ok.is_ok(), "{ok:?}");
    let e = parse_err(&small_manifest(&format!("{mcap}\ntime_column = \"t\""), ""));
    assert!(e.contains("`time_column` is not for format = \"mcap\"") && e.contains("time = \"log\""), "{e}");
    let e = parse_err(&small_manifest("file = \"w.csv\"\ntime_column = \"t\"\ntime = \"log\"", ""));
    assert!(e.contains("`time` is only for format = \"mcap\""), "{e}");
    let e = parse_err(&small_manifest(&format!("{mcap}\ntime = \"gps\""), ""));
    assert!(e.contains("streams.wheels") && e.contains("gps"), "{e}");
}

#[test]
fn quality_thresholds() {
    let csv = "file = \"w.csv\"\ntime_column = \"t\"";
    let e = parse_err(&small_manifest(csv, "quality = { column = \"q\" }"));
    assert!(e.contains("pose.quality.accept: no accepted values given"), "{e}");
    let e = parse_err(&small_manifest(csv, "quality = { column = \"q\", max = nan }"));
    assert!(e.contains("pose.quality.max: must be a finite number"), "{e}");
    // Which values pass: the unit tests in src/io/import/manifest.rs.
}

/// Without the `mcap` feature a bag stream is an error naming the feature.
#[cfg(not(feature = "mcap"))]
#[test]
fn mcap_stream_without_the_feature_says_so() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/psu-mapping-van");
    let text = small_manifest("format = \"mcap\"\nfile = \"drive-slice.mcap\"\ntopic = \"/w\"", "");
    let m = Manifest::parse(&text, &dir.join("m.toml")).expect("manifest");
    let e = import(&m).err().map(|e| e.to_string()).unwrap_or_default();
    assert!(e.contains("cargo feature `mcap`") && e.contains("this build lacks"), "{e}");
}
