//! `format = "mcap"` manifests through the importer: the shipped slice bag,
//! and the full PSU mapping-van bag against the CSV manifest that uses the
//! same clocks (`examples/psu-mapping-van/manifest-ros-time.toml`).
#![cfg(feature = "mcap")]

use odocal::{import, Manifest};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

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
#[test]
fn full_bag_imports_as_the_ros_time_csv_manifest() {
    let bag = root().join("../shared/data/psu-mapping-van-2024-07-11/drive.mcap");
    if !bag.exists() {
        eprintln!("skipped: {} is absent (CI has ../shared/data beside the clone)", bag.display());
        return;
    }
    let from_bag = import(&load("examples/psu-mapping-van/manifest-mcap.toml")).expect("bag import");
    let from_csv = import(&load("examples/psu-mapping-van/manifest-ros-time.toml")).expect("CSV import");
    let (a, b) = (&from_bag.drive, &from_csv.drive);
    assert_eq!(a.parts(), b.parts(), "parts");
    assert_eq!(a.len(), b.len());
    assert!(a.parts().len() >= 5, "the van drive has several parts, found {}", a.parts().len());
    assert_eq!(
        from_bag.report.clock_offset.applied_s.to_bits(),
        from_csv.report.clock_offset.applied_s.to_bits(),
        "clock offset"
    );
    let max_diff = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(p, q)| (p - q).abs()).fold(0.0, f64::max);
    assert_eq!(max_diff(a.t(), b.t()), 0.0, "time");
    let pos = max_diff(a.px(), b.px()).max(max_diff(a.py(), b.py()));
    assert!(pos <= 1e-3, "positions differ by {pos} m");
    let wheels = max_diff(a.n_rl(), b.n_rl()).max(max_diff(a.n_rr(), b.n_rr()));
    assert!(wheels <= 1e-6, "wheel rotations differ by {wheels} rev/s");
    let psi = max_diff(a.psi(), b.psi());
    assert!(psi <= 1e-9, "headings differ by {psi} rad");
    // Quality: the bag's covariance threshold rejects exactly the rows the
    // CSV's both_fix6 = 0 rejects.
    assert_eq!(from_bag.report.gaps.len(), from_csv.report.gaps.len(), "gaps");
}

/// The shipped 120 s slice bag imports: both wheels, the pose, its quality
/// threshold; and `time = "log"` gives the same drive (this bag's log time is
/// its header stamp).
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
    let d = &header.drive;
    // 120 s of bag; the first pose samples are not RTK fixed (cov_x = 100).
    let span = d.t().last().copied().unwrap_or(0.0) - d.t()[0];
    assert!(span > 60.0 && span < 120.0, "span {span} s");
    assert!(!header.report.gaps.is_empty(), "the slice starts with rejected pose quality");
    let why = header.report.gaps[0].reasons.join("; ");
    assert!(why.contains("cov_x"), "{why}");
    let moving = d.n_rl().iter().filter(|n| **n > 1.0).count();
    assert!(moving > d.len() / 2, "the van drives through most of the slice ({moving} of {} samples)", d.len());
    let log = run("log");
    assert_eq!(log.drive.parts(), d.parts());
    assert_eq!(log.drive.px(), d.px());
}
