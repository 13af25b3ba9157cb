//! The PSU mapping-van bags (written by `rosbags`, a different library from
//! the one odocal reads with) against the CSVs they were made from; see
//! `data/psu-mapping-van-2024-07-11/MCAP.md` for how.
//!
//! The slice bag is in `tests/data/psu-mapping-van/`; it covers the first
//! 120 s of the drive, before the CSV fixtures there, so it is checked
//! against the full CSVs in `data/psu-mapping-van-2024-07-11/`. The full bag
//! there is checked against the fixture CSVs.
#![cfg(feature = "mcap")]

use odocal::io::bag::{self, TimeSource};
use std::collections::HashMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

/// Yaw goes through a quaternion written from float64 (MCAP.md checks 1e-12).
const YAW_TOL_RAD: f64 = 1e-12;
/// The tolerance on the wheel angle; the bag was written with the same
/// float64 formula (MCAP.md), so it is met with room.
const WHEEL_TOL_RAD: f64 = 1e-9;

const JOINTS: &str = "/vehicle/wheel_joint_states";
const POSE: &str = "/localization/pose_with_covariance";
const LEFT: &str = "position.rear_left_wheel_joint";
const RIGHT: &str = "position.rear_right_wheel_joint";

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/psu-mapping-van").join(name)
}

fn full_log(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/psu-mapping-van-2024-07-11").join(name)
}

/// A CSV as text fields by column name.
fn csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().expect("header").split(',').map(str::to_string).collect();
    let rows = lines.filter(|l| !l.is_empty()).map(|l| l.split(',').map(str::to_string).collect()).collect();
    (header, rows)
}

fn col(header: &[String], name: &str) -> usize {
    header.iter().position(|h| h == name).unwrap_or_else(|| panic!("no column {name}"))
}

fn num(s: &str) -> f64 {
    s.parse().unwrap_or_else(|_| panic!("'{s}' is not a number"))
}

/// Checks JointState positions against `left_ticks_cum`/`right_ticks_cum`
/// rows, matched by time (the stamp is the row's `ros_time_s`).
fn check_wheels(table: &bag::Table, csv_path: &Path) -> usize {
    let (h, rows) = csv(csv_path);
    let (it, il, ir) = (col(&h, "ros_time_s"), col(&h, "left_ticks_cum"), col(&h, "right_ticks_cum"));
    let by_time: HashMap<u64, usize> = table.t_s.iter().enumerate().map(|(i, t)| (t.to_bits(), i)).collect();
    let rad_per_tick = 2.0 * PI / 40360.0;
    let (left, right) = (&table.columns[LEFT], &table.columns[RIGHT]);
    let mut matched = 0;
    for r in &rows {
        let Some(&i) = by_time.get(&num(&r[it]).to_bits()) else { continue };
        let (l, rr) = (num(&r[il]) * rad_per_tick, num(&r[ir]) * rad_per_tick);
        assert!((left[i] - l).abs() <= WHEEL_TOL_RAD, "t {}: left {} vs {l}", r[it], left[i]);
        assert!((right[i] - rr).abs() <= WHEEL_TOL_RAD, "t {}: right {} vs {rr}", r[it], right[i]);
        matched += 1;
    }
    matched
}

/// Checks pose x, y (exact) and yaw against the pose CSV rows by `ros_time_s`.
fn check_pose(table: &bag::Table, csv_path: &Path) -> usize {
    let (h, rows) = csv(csv_path);
    let (it, ix, iy, iyaw, ifix) = (
        col(&h, "ros_time_s"),
        col(&h, "x_east_m"),
        col(&h, "y_north_m"),
        col(&h, "yaw_enu_rad"),
        col(&h, "both_fix6"),
    );
    let by_time: HashMap<u64, usize> = table.t_s.iter().enumerate().map(|(i, t)| (t.to_bits(), i)).collect();
    let mut matched = 0;
    for r in &rows {
        let Some(&i) = by_time.get(&num(&r[it]).to_bits()) else { continue };
        assert_eq!(table.columns["x"][i].to_bits(), num(&r[ix]).to_bits(), "x at {}", r[it]);
        assert_eq!(table.columns["y"][i].to_bits(), num(&r[iy]).to_bits(), "y at {}", r[it]);
        let d = (table.columns["yaw"][i] - num(&r[iyaw]) + PI).rem_euclid(2.0 * PI) - PI;
        assert!(d.abs() <= YAW_TOL_RAD, "yaw at {}: {} vs {}", r[it], table.columns["yaw"][i], r[iyaw]);
        let (cov_xy, cov_yaw) = if r[ifix] == "1" { (0.0004, 2.5e-5) } else { (100.0, 1.0) };
        assert_eq!(table.columns["cov_x"][i].to_bits(), f64::to_bits(cov_xy));
        assert_eq!(table.columns["cov_yaw"][i].to_bits(), f64::to_bits(cov_yaw));
        matched += 1;
    }
    matched
}

#[test]
fn slice_has_the_documented_topics_and_counts() {
    let p = fixture("drive-slice.mcap");
    let info = bag::inspect(&p).expect("inspect");
    let counts: Vec<(&str, u64)> = info.topics.iter().map(|t| (t.topic.as_str(), t.count)).collect();
    assert_eq!(
        counts,
        [
            (POSE, 1063),
            ("/sensing/gnss/front/nav_sat_fix", 1084),
            ("/sensing/gnss/rear_left/nav_sat_fix", 1065),
            ("/sensing/gnss/rear_right/nav_sat_fix", 1180),
            (JOINTS, 11832),
        ]
    );
    assert_eq!(info.message_count, 16_224);
    for t in &info.topics {
        let table = bag::read_topic(&p, &t.topic, &[], TimeSource::HeaderStamp).expect("read");
        assert_eq!(table.t_s.len() as u64, t.count, "{}", t.topic);
        // Every stamp equals the log time here (MCAP.md).
        let log = bag::read_topic(&p, &t.topic, &[], TimeSource::LogTime).expect("read");
        assert_eq!(table, bag::Table { source: table.source.clone(), ..log });
    }
}

#[test]
fn slice_inspect_output() {
    let info = bag::inspect(fixture("drive-slice.mcap")).expect("inspect");
    let want = "\
Files:             drive-slice.mcap
Bag size:          932.1 KiB
Storage id:        mcap (profile 'ros2', written by 'rosbags-0.11.9')
Compression:       zstd (3 chunks)
Duration:          119.996968000s
Start:             1720717537.428161000 (log time, s since the epoch)
End:               1720717657.425129000
Messages:          16224
Topic information: Topic: /localization/pose_with_covariance   | Type: geometry_msgs/msg/PoseWithCovarianceStamped | Count:  1063 | Rate:   8.96 Hz | Serialization Format: cdr
                   Topic: /sensing/gnss/front/nav_sat_fix      | Type: sensor_msgs/msg/NavSatFix                   | Count:  1084 | Rate:   9.14 Hz | Serialization Format: cdr
                   Topic: /sensing/gnss/rear_left/nav_sat_fix  | Type: sensor_msgs/msg/NavSatFix                   | Count:  1065 | Rate:   8.98 Hz | Serialization Format: cdr
                   Topic: /sensing/gnss/rear_right/nav_sat_fix | Type: sensor_msgs/msg/NavSatFix                   | Count:  1180 | Rate:   9.95 Hz | Serialization Format: cdr
                   Topic: /vehicle/wheel_joint_states          | Type: sensor_msgs/msg/JointState                  | Count: 11832 | Rate:  98.59 Hz | Serialization Format: cdr
";
    assert_eq!(info.to_string(), want);
    assert_eq!(info.compression, Some(vec!["zstd".to_string()]));
    assert_eq!(info.chunk_count, Some(3));
}

#[test]
fn slice_wheels_are_the_encoder_ticks_in_radians() {
    let p = fixture("drive-slice.mcap");
    let t = bag::read_topic(&p, JOINTS, &[LEFT, RIGHT], TimeSource::HeaderStamp).expect("read");
    assert_eq!(t.t_s.len(), 11_832);
    // The slice is the first 11,832 encoder rows; every one matches.
    assert_eq!(check_wheels(&t, &full_log("encoders.csv")), 11_832);
    assert_eq!((t.columns[LEFT][0], t.columns[RIGHT][0]), (0.0, 0.0));
}

#[test]
fn slice_pose_and_gnss_match_their_csvs() {
    let p = fixture("drive-slice.mcap");
    let pose =
        bag::read_topic(&p, POSE, &["x", "y", "yaw", "cov_x", "cov_yaw"], TimeSource::HeaderStamp).expect("pose");
    assert_eq!(check_pose(&pose, &full_log("pose_rear_antenna_mid.csv")), 1063);

    for (topic, file, n) in [
        ("/sensing/gnss/front/nav_sat_fix", "gnss_front.csv", 1084),
        ("/sensing/gnss/rear_left/nav_sat_fix", "gnss_left_rear.csv", 1065),
        ("/sensing/gnss/rear_right/nav_sat_fix", "gnss_right_rear.csv", 1180),
    ] {
        let fix = bag::read_topic(&p, topic, &[], TimeSource::HeaderStamp).expect("fix");
        let (h, rows) = csv(&full_log(file));
        let (it, ilat, ilon, ialt, imode) =
            (col(&h, "ros_time_s"), col(&h, "lat_deg"), col(&h, "lon_deg"), col(&h, "alt_m"), col(&h, "fix_mode"));
        assert_eq!(fix.t_s.len(), n);
        for (i, r) in rows.iter().take(n).enumerate() {
            assert_eq!(fix.t_s[i].to_bits(), num(&r[it]).to_bits(), "{topic} row {i}");
            assert_eq!(fix.columns["latitude"][i].to_bits(), num(&r[ilat]).to_bits(), "{topic} row {i}");
            assert_eq!(fix.columns["longitude"][i].to_bits(), num(&r[ilon]).to_bits(), "{topic} row {i}");
            assert_eq!(fix.columns["altitude"][i].to_bits(), num(&r[ialt]).to_bits(), "{topic} row {i}");
            // Modes 6 and 5 are GBAS (2), told apart by the covariance; 2 is SBAS (1).
            let (status, cov_e) = match r[imode].as_str() {
                "6" => (2.0, 0.0004),
                "5" => (2.0, 0.09),
                "2" => (1.0, 1.0),
                m => panic!("fix_mode {m} is not in this drive"),
            };
            assert_eq!(fix.columns["status"][i].to_bits(), f64::to_bits(status), "{topic} row {i}");
            assert_eq!(fix.columns["cov_e"][i].to_bits(), f64::to_bits(cov_e), "{topic} row {i}");
            assert_eq!(fix.columns["cov_u"][i].to_bits(), f64::to_bits(4.0 * cov_e), "{topic} row {i}");
        }
    }
}

#[test]
fn full_bag_matches_the_fixture_csv_rows() {
    let p = full_log("drive.mcap");
    let t = bag::read_topic(&p, JOINTS, &[LEFT, RIGHT], TimeSource::HeaderStamp).expect("read");
    assert_eq!(t.t_s.len(), 57_470);
    // The fixture's 13,000 encoder rows (ros time 1720717700–830) are all in the bag.
    assert_eq!(check_wheels(&t, &fixture("encoders.csv")), 13_000);
    let pose = bag::read_topic(&p, POSE, &[], TimeSource::HeaderStamp).expect("pose");
    assert_eq!(pose.t_s.len(), 5_232);
    // Fixture pose rows are selected by GPS time; all 1,191 have a bag message.
    assert_eq!(check_pose(&pose, &fixture("pose_rear_antenna_mid.csv")), 1_191);
    // MCAP.md's spot values for the last joint message.
    let n = t.t_s.len() - 1;
    assert_eq!(t.columns[LEFT][n].to_bits(), 39005.79643703454f64.to_bits());
    assert_eq!(t.columns[RIGHT][n].to_bits(), 39075.74700206227f64.to_bits());
}

/// The draft manifest of the slice names the van's topics and rear joints,
/// and imports as it stands: the same wheel and pose samples the hand-written
/// manifest's topics give (the draft has no de-jittering and no quality
/// filter, so the drive itself may differ in its cuts).
#[test]
fn slice_draft_manifest_imports() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::copy(fixture("drive-slice.mcap"), dir.path().join("bag.mcap")).expect("copy");
    let text = bag::inspect(dir.path().join("bag.mcap")).and_then(|i| i.draft_manifest("bag.mcap")).expect("draft");
    for want in [
        "topic = \"/vehicle/wheel_joint_states\"",
        "signal = \"rad_cumulative\"",
        "rear_left = { column = \"position.rear_left_wheel_joint\" }\n",
        "rear_right = { column = \"position.rear_right_wheel_joint\" }\n",
        "topic = \"/localization/pose_with_covariance\"",
        "source = \"from_wheels\"",
    ] {
        assert!(text.contains(want), "expected '{want}' in:\n{text}");
    }
    assert!(!text.contains("a guess from the joint names"), "{text}");
    let path = dir.path().join("draft.toml");
    std::fs::write(&path, &text).expect("write");
    let m = odocal::Manifest::from_path(&path).expect("the draft parses");
    let (drive, _) = odocal::import(&m).expect("the draft imports");
    // 120 s of a van at highway speed, every sample of one continuous part.
    assert!(drive.distance_m() > 2000.0, "{} m", drive.distance_m());
    assert!(drive.len() > 40 * 100, "{} samples", drive.len());
}
