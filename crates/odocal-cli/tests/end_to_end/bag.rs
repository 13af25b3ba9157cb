//! ROS 2 bags through the CLI: `odocal inspect` on the shipped slice bag, and
//! every bag error of a `format = "mcap"` manifest through `odocal import`,
//! with its exact one-line message (exit code 1).

use crate::common;

use std::path::{Path, PathBuf};

use common::odocal;

const WHEELS: &str = "/vehicle/wheel_joint_states";
const POSE: &str = "/localization/pose_with_covariance";
/// The slice bag's topics as the errors list them.
const TOPICS: &str = "/localization/pose_with_covariance (geometry_msgs/msg/PoseWithCovarianceStamped), \
                      /sensing/gnss/front/nav_sat_fix (sensor_msgs/msg/NavSatFix), \
                      /sensing/gnss/rear_left/nav_sat_fix (sensor_msgs/msg/NavSatFix), \
                      /sensing/gnss/rear_right/nav_sat_fix (sensor_msgs/msg/NavSatFix), \
                      /vehicle/wheel_joint_states (sensor_msgs/msg/JointState)";

fn slice() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../odocal/tests/data/psu-mapping-van/drive-slice.mcap")
}

/// A manifest reading the wheels from `wheels_topic` (column `left`) and the
/// pose from the slice bag's pose topic.
fn manifest(dir: &Path, bag: &Path, wheels_topic: &str, left: &str) -> PathBuf {
    let bag = bag.display();
    let text = format!(
        r#"
[streams.wheels]
format = "mcap"
file = "{bag}"
topic = "{wheels_topic}"

[streams.pose]
format = "mcap"
file = "{slice}"
topic = "{POSE}"

[wheels]
stream = "wheels"
signal = "rad_cumulative"
rear_left = {{ column = "{left}" }}
rear_right = {{ column = "position.rear_right_wheel_joint" }}

[pose]
stream = "pose"
position = {{ kind = "local", x = "x", y = "y" }}
quality = {{ column = "cov_x", max = 0.01 }}
"#,
        slice = slice().display()
    );
    let p = dir.join("m.toml");
    std::fs::write(&p, text).expect("write manifest");
    p
}

/// Runs `odocal import` on the manifest and asserts exit code 1 and exactly
/// `error: <manifest>: <message>`.
fn assert_import_error(m: &Path, message: &str) {
    let out = m.with_extension("csv");
    let o = odocal(&["import", m.to_str().expect("utf8"), "--out", out.to_str().expect("utf8")]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "stderr: {stderr}");
    assert_eq!(stderr.trim_end(), format!("error: {}: {message}", m.display()));
    assert!(!out.exists(), "no output on error");
}

#[test]
fn inspect_lists_topics_types_counts_and_rates() {
    let o = odocal(&["inspect", slice().to_str().expect("utf8")]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for needle in [
        "Files:             drive-slice.mcap",
        "Storage id:        mcap (profile 'ros2', written by 'rosbags-0.11.9')",
        "Compression:       zstd (3 chunks)",
        "Messages:          16224",
        "Topic: /vehicle/wheel_joint_states          | Type: sensor_msgs/msg/JointState",
        "| Count: 11832 |",
        "Topic: /localization/pose_with_covariance   | Type: geometry_msgs/msg/PoseWithCovarianceStamped | Count:  1063",
        "Serialization Format: cdr",
        "  /vehicle/wheel_joint_states: position.<joint name>, velocity.<joint name>\n    joints: ",
        "rear_left_wheel_joint, rear_right_wheel_joint",
        "  /sensing/gnss/front/nav_sat_fix: latitude, longitude, altitude, status, cov_e, cov_n, cov_u",
    ] {
        assert!(text.contains(needle), "expected '{needle}' in:\n{text}");
    }
    assert_eq!(text.matches(" Hz | ").count(), 5, "a rate per topic:\n{text}");
}

/// `inspect --manifest OUT` writes a draft that `odocal import` takes as it
/// stands (the bag named relative to it); it replaces a file only with
/// `--force`; without
/// a file name the draft alone goes to stdout.
#[test]
fn inspect_drafts_a_manifest_that_imports() {
    let d = tempfile::tempdir().expect("tmp");
    std::fs::copy(slice(), d.path().join("van.mcap")).expect("copy");
    let bag = d.path().join("van.mcap");
    let out = d.path().join("van.toml");
    let s = |p: &Path| p.to_str().expect("utf8").to_string();
    let o = odocal(&["inspect", &s(&bag), "--manifest", &s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&out).expect("draft");
    assert!(text.contains("file = \"van.mcap\"") && text.contains(&format!("topic = \"{WHEELS}\"")), "{text}");
    let csv = d.path().join("van.csv");
    let o = odocal(&["import", &s(&out), "--out", &s(&csv)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(std::fs::metadata(&csv).expect("csv").len() > 100_000);
    std::fs::write(&out, "# the user's edits\n").expect("edit");
    let o = odocal(&["inspect", &s(&bag), "--manifest", &s(&out)]);
    assert_eq!(o.status.code(), Some(1));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("van.toml: exists; give another name, or --force to replace it"), "{e}");
    assert_eq!(std::fs::read_to_string(&out).expect("kept"), "# the user's edits\n");
    let o = odocal(&["inspect", &s(&bag), "--manifest", &s(&out), "--force"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(std::fs::read_to_string(&out).expect("draft").starts_with("# Draft manifest"));
    let o = odocal(&["inspect", &s(&bag), "--manifest"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let printed = String::from_utf8_lossy(&o.stdout);
    assert!(printed.starts_with("# Draft manifest") && !printed.contains("Topic information"), "{printed}");
    // On stdout the bag is named by its absolute path.
    assert!(printed.contains(&format!("file = {}", toml_quoted(&s(&bag.canonicalize().expect("abs"))))), "{printed}");
}

fn toml_quoted(s: &str) -> String {
    format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""))
}

#[test]
fn unknown_topic_names_it_and_lists_the_bags_topics() {
    let d = tempfile::tempdir().expect("tmp");
    let m = manifest(d.path(), &slice(), "/wheels", "position.rear_left_wheel_joint");
    let msg =
        format!("streams.wheels.topic: {}: no topic '/wheels' in the bag; its topics: {TOPICS}", slice().display());
    assert_import_error(&m, &msg);
}

#[test]
fn topic_of_another_type_names_it_and_lists_its_columns() {
    let d = tempfile::tempdir().expect("tmp");
    let m = manifest(d.path(), &slice(), POSE, "position.rear_left_wheel_joint");
    let msg = format!(
        "wheels.rear_left.column: {}: topic '{POSE}' (geometry_msgs/msg/PoseWithCovarianceStamped) has no column \
         'position.rear_left_wheel_joint'; valid columns: x, y, z, yaw, cov_x, cov_y, cov_yaw",
        slice().display()
    );
    assert_import_error(&m, &msg);
}

#[test]
fn unsupported_message_type_names_it_and_lists_the_readable_types() {
    let d = tempfile::tempdir().expect("tmp");
    let bag = d.path().join("strings.mcap");
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .create(std::io::BufWriter::new(std::fs::File::create(&bag).expect("create")))
        .expect("writer");
    let schema = w.add_schema("std_msgs/msg/String", "ros2msg", b"string data").expect("schema");
    let ch = w.add_channel(schema, WHEELS, "cdr", &Default::default()).expect("channel");
    let h = mcap::records::MessageHeader { channel_id: ch, sequence: 0, log_time: 1, publish_time: 1 };
    w.write_to_known_channel(&h, &[0, 1, 0, 0, 1, 0, 0, 0, 0]).expect("write");
    w.finish().expect("finish");
    drop(w);
    let m = manifest(d.path(), &bag, WHEELS, "position.rear_left_wheel_joint");
    let msg = format!(
        "streams.wheels.topic: {}: topic '{WHEELS}' has message type 'std_msgs/msg/String', which odocal cannot \
         read; supported types: sensor_msgs/msg/JointState, geometry_msgs/msg/PoseWithCovarianceStamped, \
         geometry_msgs/msg/PoseStamped, nav_msgs/msg/Odometry, sensor_msgs/msg/NavSatFix, sensor_msgs/msg/Imu",
        bag.display()
    );
    assert_import_error(&m, &msg);
}

#[test]
fn missing_joint_names_it_and_lists_the_joints_present() {
    let d = tempfile::tempdir().expect("tmp");
    let m = manifest(d.path(), &slice(), WHEELS, "position.rear_left_wheel");
    let msg = format!(
        "wheels.rear_left.column: {}: topic '{WHEELS}': no joint named 'rear_left_wheel' in message 0 (log time \
         1720717537.428161000 s); joint names present: rear_left_wheel_joint, rear_right_wheel_joint",
        slice().display()
    );
    assert_import_error(&m, &msg);
}

#[test]
fn sqlite_bag_gets_the_convert_hint() {
    let d = tempfile::tempdir().expect("tmp");
    let bag = d.path().join("drive_0.db3");
    std::fs::write(&bag, b"SQLite format 3\0rest of the database").expect("write");
    let m = manifest(d.path(), &bag, WHEELS, "position.rear_left_wheel_joint");
    let msg = format!(
        "streams.wheels.file: {}: a ROS 2 sqlite3 (.db3) bag; odocal reads MCAP bags: convert it with `ros2 bag \
         convert -i BAG -o out.yaml`, out.yaml being `output_bags: [{{uri: BAG_mcap, storage_id: mcap, \
         all_topics: true}}]`",
        bag.display()
    );
    assert_import_error(&m, &msg);
}

/// The import command `inspect --manifest` suggests runs as printed, in a
/// shell, whatever the characters of the draft's path.
#[test]
fn inspect_suggests_an_import_command_a_shell_runs() {
    let d = tempfile::tempdir().expect("tmp");
    let weird = d.path().join("we\"ird\\dir #x 'q'");
    std::fs::create_dir(&weird).expect("dir");
    let bag = weird.join("van.mcap");
    std::fs::copy(slice(), &bag).expect("copy");
    let out = weird.join("draft.toml");
    let s = |p: &Path| p.to_str().expect("utf8").to_string();
    let o = odocal(&["inspect", &s(&bag), "--manifest", &s(&out)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let printed = String::from_utf8_lossy(&o.stdout).into_owned();
    let command = printed.split("then: ").nth(1).and_then(|c| c.trim_end().strip_suffix(')')).expect("a command");
    let command = command.replacen("odocal", &format!("'{}' -q", env!("CARGO_BIN_EXE_odocal")), 1);
    let o = std::process::Command::new("sh").current_dir(d.path()).args(["-c", &command]).output().expect("sh");
    assert!(o.status.success(), "{command}: {}", String::from_utf8_lossy(&o.stderr));
    assert!(d.path().join("drive.csv").exists());
}
