//! Bags written here with the `mcap` writer (uncompressed) and CDR-encoded
//! with `cdr-encoding`, and the same content compressed with lz4 and zstd by
//! the C libraries (committed: tests/data/compressed-bags/), read back
//! exactly; every error case with its exact message; malformed input never
//! panics.

use super::msg::{self, encode};
use super::*;
use proptest::prelude::*;
use std::f64::consts::PI;

/// Yaw goes through a quaternion (sin/cos of ψ/2, then atan2): a few ulp.
const YAW_TOL_RAD: f64 = 1e-15;

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn header(sec: i32, nanosec: u32, frame: &str) -> msg::Header {
    msg::Header { stamp: msg::Time { sec, nanosec }, frame_id: frame.into() }
}

fn yaw_quat(yaw: f64) -> msg::Quaternion {
    msg::Quaternion { x: 0.0, y: 0.0, z: (yaw / 2.0).sin(), w: (yaw / 2.0).cos() }
}

fn cov6(x: f64, y: f64, yaw: f64) -> msg::Cov6 {
    let mut c = [0.0; 36];
    c[0] = x;
    c[7] = y;
    c[14] = 1e6;
    c[35] = yaw;
    msg::Cov6(c)
}

/// One topic's messages: (log time ns, CDR bytes).
struct Topic {
    name: &'static str,
    ty: &'static str,
    encoding: &'static str,
    messages: Vec<(u64, Vec<u8>)>,
}

/// Writes `topics` as an uncompressed bag, chunks of 2048 bytes, with or
/// without a summary section. The committed compressed bags
/// (tests/data/compressed-bags/) were written with these options.
fn write_bag(path: &Path, summary: bool, topics: &[Topic]) {
    let opts = mcap::WriteOptions::new()
        .compression(None)
        .profile("ros2")
        .chunk_size(Some(2048))
        .emit_summary_records(summary)
        .emit_summary_offsets(summary)
        .emit_statistics(summary)
        .emit_chunk_indexes(summary)
        .emit_message_indexes(summary);
    let mut w = opts.create(std::io::BufWriter::new(File::create(path).expect("create"))).expect("writer");
    let mut msgs = Vec::new();
    for t in topics {
        let schema = w.add_schema(t.ty, "ros2msg", b"# definition not needed by odocal").expect("schema");
        let ch = w.add_channel(schema, t.name, t.encoding, &BTreeMap::new()).expect("channel");
        msgs.extend(t.messages.iter().map(|(log, data)| (*log, ch, data.clone())));
    }
    msgs.sort_by_key(|m| m.0);
    for (log_time, channel_id, data) in msgs {
        let h = mcap::records::MessageHeader { channel_id, sequence: 0, log_time, publish_time: log_time };
        w.write_to_known_channel(&h, &data).expect("write");
    }
    w.finish().expect("finish");
}

const T0: i32 = 1_720_717_537;

fn joint_states() -> Topic {
    let names = |a: &str, b: &str| vec![a.to_string(), b.to_string()];
    let mut messages = Vec::new();
    for i in 0..50u32 {
        let p = f64::from(i) * 0.1 + 1e-7;
        // Every fifth message lists the joints the other way round.
        let (name, position, velocity) = if i % 5 == 3 {
            (names("right", "left"), vec![-p, p], vec![-2.0, 2.0])
        } else {
            (names("left", "right"), vec![p, -p], vec![2.0, -2.0])
        };
        let m = msg::JointState {
            header: header(T0, i * 10_000_000 + 123, "base_link"),
            name,
            position,
            velocity,
            effort: vec![],
        };
        messages.push((u64::from(i) * 10_000_000 + 5_000, encode(&m)));
    }
    Topic { name: "/joints", ty: "sensor_msgs/msg/JointState", encoding: "cdr", messages }
}

fn pose_msgs() -> Vec<Topic> {
    let mut pwc = Vec::new();
    let mut ps = Vec::new();
    let mut odom = Vec::new();
    for i in 0..20u32 {
        let f = f64::from(i);
        let pose = msg::Pose {
            position: msg::Vector3 { x: 10.0 + f, y: -5.0 - f / 3.0, z: 0.25 },
            orientation: yaw_quat(-PI + 0.3 * f),
        };
        let h = header(T0 + 1 + (i / 10) as i32, (i % 10) * 100_000_000, "map");
        let pc = msg::PoseWithCovariance { pose, covariance: cov6(0.0004 * f, 0.0005, 2.5e-5) };
        pwc.push((u64::from(i) * 100_000_000, encode(&msg::PoseWithCovarianceStamped { header: h.clone(), pose: pc })));
        ps.push((u64::from(i) * 100_000_000, encode(&msg::PoseStamped { header: h.clone(), pose })));
        let twist = msg::TwistWithCovariance {
            twist: msg::Twist {
                linear: msg::Vector3 { x: 3.0 + f, y: 0.1, z: 0.0 },
                angular: msg::Vector3 { x: 0.0, y: 0.0, z: -0.01 * f },
            },
            covariance: msg::Cov6::default(),
        };
        let o = msg::Odometry { header: h, child_frame_id: "base_link".into(), pose: pc, twist };
        odom.push((u64::from(i) * 100_000_000, encode(&o)));
    }
    vec![
        Topic { name: "/pose", ty: "geometry_msgs/msg/PoseWithCovarianceStamped", encoding: "cdr", messages: pwc },
        Topic { name: "/pose_stamped", ty: "geometry_msgs/msg/PoseStamped", encoding: "cdr", messages: ps },
        Topic { name: "/odom", ty: "nav_msgs/msg/Odometry", encoding: "cdr", messages: odom },
    ]
}

fn fix_and_imu() -> Vec<Topic> {
    let mut fix = Vec::new();
    let mut imu = Vec::new();
    for i in 0..10u32 {
        let f = f64::from(i);
        let m = msg::NavSatFix {
            header: header(T0 + 2 + (i / 10) as i32, (i % 10) * 100_000_000, "gnss"),
            status: msg::NavSatStatus { status: (i % 4) as i8 - 2, service: 1 },
            latitude: 40.442130345 + f * 1e-6,
            longitude: -79.760361018,
            altitude: if i == 3 { f64::NAN } else { 322.692 },
            position_covariance: [0.0004, 0.0, 0.0, 0.0, 0.0009, 0.0, 0.0, 0.0, 0.0016],
            position_covariance_type: 1,
        };
        fix.push((u64::from(i) * 100_000_000, encode(&m)));
        let m = msg::Imu {
            header: header(T0 + 3, i, "imu"),
            orientation: yaw_quat(0.1),
            orientation_covariance: [-1.0; 9],
            angular_velocity: msg::Vector3 { x: 0.01, y: -0.02, z: 0.3 * f },
            angular_velocity_covariance: [0.0; 9],
            linear_acceleration: msg::Vector3 { x: 0.5, y: -1.5 * f, z: 9.81 },
            linear_acceleration_covariance: [0.0; 9],
        };
        imu.push((u64::from(i) * 100_000_000 + 1, encode(&m)));
    }
    let string = Topic {
        name: "/chatter",
        ty: "std_msgs/msg/String",
        encoding: "cdr",
        messages: vec![(1, vec![0, 1, 0, 0, 3, 0, 0, 0, b'h', b'i', 0])],
    };
    vec![
        Topic { name: "/fix", ty: "sensor_msgs/msg/NavSatFix", encoding: "cdr", messages: fix },
        Topic { name: "/imu", ty: "sensor_msgs/msg/Imu", encoding: "cdr", messages: imu },
        string,
    ]
}

fn all_topics() -> Vec<Topic> {
    let mut v = vec![joint_states()];
    v.extend(pose_msgs());
    v.extend(fix_and_imu());
    v
}

/// The chunk compressions of the bags of [`all_topics`] the tests read.
const COMPRESSIONS: [&str; 3] = ["none", "lz4", "zstd"];

/// The committed bag of [`all_topics`] whose chunks `compression` (`lz4`
/// or `zstd`) compressed, with or without a summary section.
fn compressed_bag(compression: &str, summary: bool) -> PathBuf {
    let name = if summary { format!("{compression}.mcap") } else { format!("{compression}-nosummary.mcap") };
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/compressed-bags").join(name)
}

/// The bag of [`all_topics`] with `compression` (one of [`COMPRESSIONS`])
/// and with or without a summary: uncompressed, written into `dir`;
/// compressed, the committed one ([`compressed_bag`]).
fn test_bag(dir: &tempfile::TempDir, compression: &str, summary: bool) -> PathBuf {
    if compression == "none" {
        let p = dir.path().join(format!("none-{summary}.mcap"));
        write_bag(&p, summary, &all_topics());
        p
    } else {
        compressed_bag(compression, summary)
    }
}

/// A message as the bag holds it: topic, schema name, message encoding,
/// sequence, log and publish times, bytes.
type RawMessage = (String, String, String, u32, u64, u64, Vec<u8>);

/// Every message of the bag at `p` in file order, read as [`read_topic`]
/// reads (chunks decompressed by `decompress::ChunkDecoder`, CRCs checked).
fn raw_messages(p: &Path) -> Vec<RawMessage> {
    let mut bag = Bag::open(p).expect("opens");
    let summary = bag.summary();
    let mut out = Vec::new();
    bag.scan(summary.as_ref(), |m| {
        let c = &m.channel;
        let schema = c.schema.as_ref().map(|s| s.name.clone()).unwrap_or_default();
        out.push((
            c.topic.clone(),
            schema,
            c.message_encoding.clone(),
            m.sequence,
            m.log_time,
            m.publish_time,
            m.data.to_vec(),
        ));
        Ok(ControlFlow::Continue(()))
    })
    .expect("scans");
    out
}

/// The committed lz4 and zstd bags hold what the tests' writer writes
/// uncompressed from [`all_topics`] at test time: the same messages, byte for byte
/// and in the same order, every column of every readable topic to the bit
/// on either clock, and the same [`inspect`] but for the compression. A
/// change to the content builders or to the writer (which the fixtures
/// would then no longer match), or to the decoders, fails here.
#[test]
fn committed_compressed_bags_hold_what_the_tests_write_uncompressed() {
    let dir = tempfile::tempdir().expect("tempdir");
    for summary in [true, false] {
        let plain = test_bag(&dir, "none", summary);
        let want = raw_messages(&plain);
        assert_eq!(want.len(), 131);
        let want_info = inspect(&plain).expect("inspect");
        for label in ["lz4", "zstd"] {
            let p = compressed_bag(label, summary);
            let ctx = format!("{label}, summary {summary}");
            assert_eq!(raw_messages(&p), want, "{ctx}");
            // Every column of each readable topic, or the same error (the
            // IMU's header stamps are all within one second: refused).
            let mut tables = 0;
            for t in all_topics() {
                if MessageType::from_ros_name(t.ty).is_none() {
                    continue;
                }
                for time in [TimeSource::HeaderStamp, TimeSource::LogTime] {
                    let read = |p: &Path| {
                        read_topic(p, t.name, &[], time)
                            .map_err(|e| e.to_string().replace(&p.display().to_string(), "BAG"))
                    };
                    let (got, exp) = (read(&p), read(&plain));
                    let what = format!("{ctx}: {} {time:?}", t.name);
                    let (Ok(got), Ok(exp)) = (&got, &exp) else {
                        assert_eq!(got.err(), exp.err(), "{what}");
                        continue;
                    };
                    tables += 1;
                    assert!(!exp.t_s.is_empty(), "{what}");
                    assert_eq!(bits(&got.t_s), bits(&exp.t_s), "{what}");
                    assert_eq!(
                        got.columns.keys().collect::<Vec<_>>(),
                        exp.columns.keys().collect::<Vec<_>>(),
                        "{what}"
                    );
                    for (name, col) in &exp.columns {
                        assert_eq!(bits(&got.columns[name]), bits(col), "{what}: {name}");
                    }
                }
            }
            assert_eq!(tables, 11, "{ctx}: six readable topics on two clocks, the IMU's stamps refused");
            let info = inspect(&p).expect(&ctx);
            let compression = summary.then(|| vec![label.to_string()]);
            let want_compression = summary.then(|| vec!["none".to_string()]);
            assert_eq!((&info.compression, &want_info.compression), (&compression, &want_compression), "{ctx}");
            let chunks = summary.then_some(16);
            assert_eq!((info.chunk_count, want_info.chunk_count), (chunks, chunks), "{ctx}");
            assert_eq!(
                BagInfo { path: plain.clone(), size_bytes: 0, compression: None, ..info },
                BagInfo { size_bytes: 0, compression: None, ..want_info.clone() },
                "{ctx}"
            );
        }
    }
}

#[test]
fn every_type_reads_back_exactly_with_each_compression() {
    let dir = tempfile::tempdir().expect("tempdir");
    for label in COMPRESSIONS {
        for summary in [true, false] {
            let p = test_bag(&dir, label, summary);
            let ctx = format!("{label}, summary {summary}");

            let j = read_topic(
                &p,
                "/joints",
                &["position.left", "position.right", "velocity.right"],
                TimeSource::HeaderStamp,
            )
            .expect(&ctx);
            assert_eq!(j.t_s.len(), 50, "{ctx}");
            let p_left: Vec<f64> = (0..50).map(|i| f64::from(i) * 0.1 + 1e-7).collect();
            let p_right: Vec<f64> = p_left.iter().map(|p| -p).collect();
            assert_eq!(bits(&j.columns["position.left"]), bits(&p_left), "{ctx}");
            assert_eq!(bits(&j.columns["position.right"]), bits(&p_right), "{ctx}");
            assert!(j.columns["velocity.right"].iter().all(|v| v.to_bits() == (-2.0f64).to_bits()));
            let t: Vec<f64> =
                (0..50).map(|i| format!("{T0}.{:09}", i * 10_000_000 + 123).parse().expect("f64")).collect();
            assert_eq!(bits(&j.t_s), bits(&t), "{ctx}");
            assert_eq!(j.columns.len(), 3);
            assert_eq!(j.source, format!("{}:/joints", p.display()));

            let pose = read_topic(&p, "/pose", &[], TimeSource::HeaderStamp).expect(&ctx);
            let odom = read_topic(&p, "/odom", &[], TimeSource::HeaderStamp).expect(&ctx);
            let ps = read_topic(&p, "/pose_stamped", &[], TimeSource::HeaderStamp).expect(&ctx);
            assert_eq!(pose.columns.keys().collect::<Vec<_>>(), ["cov_x", "cov_y", "cov_yaw", "x", "y", "yaw", "z"]);
            assert_eq!(ps.columns.keys().collect::<Vec<_>>(), ["x", "y", "yaw", "z"]);
            assert_eq!(odom.columns.len(), 9);
            for i in 0..20 {
                let f = f64::from(i as u32);
                for tab in [&pose, &odom, &ps] {
                    assert_eq!(tab.columns["x"][i].to_bits(), (10.0 + f).to_bits());
                    assert_eq!(tab.columns["y"][i].to_bits(), (-5.0 - f / 3.0).to_bits());
                    assert_eq!(tab.columns["z"][i].to_bits(), 0.25f64.to_bits());
                    let yaw = tab.columns["yaw"][i];
                    let want = -PI + 0.3 * f;
                    // ±π are the same heading.
                    let d = (yaw - want + PI).rem_euclid(2.0 * PI) - PI;
                    assert!(d.abs() <= YAW_TOL_RAD, "{ctx}: yaw {yaw} vs {want}");
                    assert!((-PI..=PI).contains(&yaw));
                }
                for tab in [&pose, &odom] {
                    assert_eq!(tab.columns["cov_x"][i].to_bits(), (0.0004 * f).to_bits());
                    assert_eq!(tab.columns["cov_y"][i].to_bits(), 0.0005f64.to_bits());
                    assert_eq!(tab.columns["cov_yaw"][i].to_bits(), 2.5e-5f64.to_bits());
                }
                assert_eq!(odom.columns["v_x"][i].to_bits(), (3.0 + f).to_bits());
                assert_eq!(odom.columns["omega_z"][i].to_bits(), (-0.01 * f).to_bits());
            }

            let fix = read_topic(&p, "/fix", &[], TimeSource::HeaderStamp).expect(&ctx);
            let lat: Vec<f64> = (0..10).map(|i| 40.442130345 + f64::from(i) * 1e-6).collect();
            assert_eq!(bits(&fix.columns["latitude"]), bits(&lat));
            assert_eq!(bits(&fix.columns["status"]), bits(&[-2.0, -1.0, 0.0, 1.0, -2.0, -1.0, 0.0, 1.0, -2.0, -1.0]));
            assert!(fix.columns["altitude"][3].is_nan());
            assert_eq!(
                bits(&[fix.columns["cov_e"][0], fix.columns["cov_n"][0], fix.columns["cov_u"][0]]),
                bits(&[0.0004, 0.0009, 0.0016])
            );

            let imu = read_topic(&p, "/imu", &["acc_y", "gyro_z", "acc_z"], TimeSource::LogTime).expect(&ctx);
            for i in 0..10 {
                let f = f64::from(i as u32);
                assert_eq!(imu.columns["acc_y"][i].to_bits(), (-1.5 * f).to_bits());
                assert_eq!(imu.columns["gyro_z"][i].to_bits(), (0.3 * f).to_bits());
                assert_eq!(imu.columns["acc_z"][i].to_bits(), 9.81f64.to_bits());
                // Log time i·0.1 s + 1 ns since 1970.
                let t: f64 = format!("0.{i}00000001").parse().expect("f64");
                assert_eq!(imu.t_s[i].to_bits(), t.to_bits());
            }
        }
    }
}

#[test]
fn all_joint_columns_come_from_the_first_message() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = test_bag(&dir, "none", true);
    let j = read_topic(&p, "/joints", &[], TimeSource::LogTime).expect("read");
    assert_eq!(
        j.columns.keys().collect::<Vec<_>>(),
        ["position.left", "position.right", "velocity.left", "velocity.right"]
    );
    assert_eq!(j.t_s[1].to_bits(), 0.010005f64.to_bits());
    // Duplicated requests give one column.
    let j = read_topic(&p, "/joints", &["position.left", "position.left"], TimeSource::LogTime).expect("read");
    assert_eq!(j.columns.len(), 1);
}

#[test]
fn rows_are_sorted_by_the_chosen_time() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("order.mcap");
    let mk = |tenths: u32, x: f64| {
        encode(&msg::PoseStamped {
            header: header(0, tenths * 100_000_000, "map"),
            pose: msg::Pose { position: msg::Vector3 { x, y: 0.0, z: 0.0 }, ..Default::default() },
        })
    };
    // Log times increase; stamps go 0.3, 0.1, 0.2, 0.1 s (out of order by
    // less than a clock step; ties keep file order).
    let messages = vec![(1, mk(3, 30.0)), (2, mk(1, 10.0)), (3, mk(2, 20.0)), (4, mk(1, 11.0))];
    write_bag(&p, true, &[Topic { name: "/p", ty: "geometry_msgs/msg/PoseStamped", encoding: "cdr", messages }]);
    let t = read_topic(&p, "/p", &["x"], TimeSource::HeaderStamp).expect("read");
    assert_eq!(bits(&t.t_s), bits(&[0.1, 0.1, 0.2, 0.3]));
    assert_eq!(bits(&t.columns["x"]), bits(&[10.0, 11.0, 20.0, 30.0]));
    let t = read_topic(&p, "/p", &["x"], TimeSource::LogTime).expect("read");
    assert_eq!(bits(&t.columns["x"]), bits(&[30.0, 10.0, 20.0, 11.0]));
}

#[test]
fn times_are_the_nearest_f64_to_the_exact_decimal() {
    for ns in [0i128, 1, 999_999_999, 1_720_717_537_428_161_000, 1_720_717_700_006_053_000, -1_500_000_000] {
        let s = ns_to_s(ns);
        let text =
            format!("{}{}.{:09}", if ns < 0 { "-" } else { "" }, ns.abs() / 1_000_000_000, ns.abs() % 1_000_000_000);
        assert_eq!(s.to_bits(), text.parse::<f64>().expect("f64").to_bits(), "{ns}");
    }
    assert_eq!(ns_to_s(-1_500_000_000).to_bits(), (-1.5f64).to_bits());
    // A negative `sec` with positive `nanosec` (ROS time before 1970): −2 s + 0.5 s.
    assert_eq!(msg::Time { sec: -2, nanosec: 500_000_000 }.total_ns(), -1_500_000_000);
    assert_eq!(human_bytes(954_473), "932.1 KiB");
    assert_eq!(human_bytes(12), "12 B");
}

fn err(p: &Path, topic: &str, cols: &[&str]) -> String {
    read_topic(p, topic, cols, TimeSource::HeaderStamp).expect_err("an error").to_string()
}

#[test]
fn unknown_topic_lists_the_topics_with_summary_or_without() {
    let dir = tempfile::tempdir().expect("tempdir");
    let topics = "/chatter (std_msgs/msg/String), /fix (sensor_msgs/msg/NavSatFix), /imu (sensor_msgs/msg/Imu), \
                  /joints (sensor_msgs/msg/JointState), /odom (nav_msgs/msg/Odometry), \
                  /pose (geometry_msgs/msg/PoseWithCovarianceStamped), /pose_stamped (geometry_msgs/msg/PoseStamped)";
    for summary in [true, false] {
        let p = test_bag(&dir, "zstd", summary);
        assert_eq!(
            err(&p, "/wheels", &[]),
            format!("{}: no topic '/wheels' in the bag; its topics: {topics}", p.display())
        );
    }
}

#[test]
fn wrong_type_column_and_joint_errors_name_file_topic_and_choices() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = test_bag(&dir, "lz4", true);
    let d = p.display();
    assert_eq!(
        err(&p, "/chatter", &[]),
        format!(
            "{d}: topic '/chatter' has message type 'std_msgs/msg/String', which odocal cannot read; supported types: \
             sensor_msgs/msg/JointState, geometry_msgs/msg/PoseWithCovarianceStamped, geometry_msgs/msg/PoseStamped, \
             nav_msgs/msg/Odometry, sensor_msgs/msg/NavSatFix, sensor_msgs/msg/Imu"
        )
    );
    assert_eq!(
        err(&p, "/pose_stamped", &["x", "cov_x"]),
        format!("{d}: topic '/pose_stamped' (geometry_msgs/msg/PoseStamped) has no column 'cov_x'; valid columns: x, y, z, yaw")
    );
    assert_eq!(
        err(&p, "/joints", &["left"]),
        format!(
            "{d}: topic '/joints' (sensor_msgs/msg/JointState) has no column 'left'; valid columns: \
             position.<joint name>, velocity.<joint name>"
        )
    );
    assert_eq!(
        err(&p, "/joints", &["position.left", "effort.left"]),
        format!(
            "{d}: topic '/joints' (sensor_msgs/msg/JointState) has no column 'effort.left'; valid columns: \
             position.<joint name>, velocity.<joint name>"
        )
    );
    assert_eq!(
        err(&p, "/joints", &["position.rear_left_wheel_joint"]),
        format!(
            "{d}: topic '/joints': no joint named 'rear_left_wheel_joint' in message 0 \
             (log time 0.000005000 s); joint names present: left, right"
        )
    );
}

#[test]
fn short_joint_arrays_non_cdr_and_bad_messages_are_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("bad.mcap");
    let good = msg::JointState { name: vec!["a".into(), "b".into()], position: vec![1.0, 2.0], ..Default::default() };
    let short = msg::JointState { position: vec![1.0], ..good.clone() };
    let mut garbled = encode(&good);
    garbled.truncate(20);
    write_bag(
        &p,
        true,
        &[
            Topic {
                name: "/j",
                ty: "sensor_msgs/msg/JointState",
                encoding: "cdr",
                messages: vec![(1, encode(&good)), (2_000_000_001, encode(&short))],
            },
            Topic { name: "/g", ty: "sensor_msgs/msg/JointState", encoding: "cdr", messages: vec![(7, garbled)] },
            Topic { name: "/e", ty: "sensor_msgs/msg/Imu", encoding: "json", messages: vec![(1, b"{}".to_vec())] },
            Topic {
                name: "/x",
                ty: "sensor_msgs/msg/Imu",
                encoding: "cdr",
                messages: vec![(1, vec![0x00, 0x03, 0, 0])],
            },
            Topic { name: "/none", ty: "sensor_msgs/msg/Imu", encoding: "cdr", messages: vec![] },
        ],
    );
    let d = p.display();
    assert_eq!(
        err(&p, "/j", &["position.b"]),
        format!("{d}: topic '/j': message 1 (log time 2.000000001 s) has 1 position values for 2 joint names")
    );
    assert_eq!(
        err(&p, "/j", &["velocity.a"]),
        format!("{d}: topic '/j': message 0 (log time 0.000000001 s) has 0 velocity values for 2 joint names")
    );
    assert_eq!(
        err(&p, "/g", &["position.a"]),
        format!(
            "{d}: topic '/g': message 0 (log time 0.000000007 s) is not a sensor_msgs/msg/JointState: \
             the message ends inside name (4 bytes needed, 0 left)"
        )
    );
    assert_eq!(
        err(&p, "/e", &[]),
        format!(
            "{d}: topic '/e': message encoding 'json' (sensor_msgs/msg/Imu); odocal reads 'cdr' (ROS 2) messages only"
        )
    );
    assert_eq!(
        err(&p, "/x", &[]),
        format!(
            "{d}: topic '/x': message 0 (log time 0.000000001 s) is not a sensor_msgs/msg/Imu: encapsulation 0x0003 \
             is not plain CDR (0x0000 big endian or 0x0001 little endian)"
        )
    );
    assert_eq!(err(&p, "/none", &[]), format!("{d}: topic '/none': no messages (sensor_msgs/msg/Imu)"));
}

#[test]
fn sqlite_bags_non_mcap_and_truncated_files_are_refused_clearly() {
    let dir = tempfile::tempdir().expect("tempdir");
    let hint =
        "a ROS 2 sqlite3 (.db3) bag; odocal reads MCAP bags: convert it with `ros2 bag convert -i BAG -o out.yaml`, \
                out.yaml being `output_bags: [{uri: BAG_mcap, storage_id: mcap, all_topics: true}]`";
    // A sqlite file, whatever its name.
    let db = dir.path().join("rosbag2_2024_07_11-13_05_37_0.db3");
    std::fs::write(&db, b"SQLite format 3\0 and then pages").expect("write");
    assert_eq!(err(&db, "/j", &[]), format!("{}: {hint}", db.display()));
    let renamed = dir.path().join("looks_like.mcap");
    std::fs::copy(&db, &renamed).expect("copy");
    assert_eq!(inspect(&renamed).expect_err("sqlite").to_string(), format!("{}: {hint}", renamed.display()));
    // A rosbag2 directory with metadata.yaml and a .db3.
    let bagdir = dir.path().join("rosbag2_sqlite");
    std::fs::create_dir(&bagdir).expect("mkdir");
    std::fs::write(bagdir.join("metadata.yaml"), "rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n")
        .expect("write");
    std::fs::copy(&db, bagdir.join("rosbag2_sqlite_0.db3")).expect("copy");
    assert_eq!(err(&bagdir, "/j", &[]), format!("{}: {hint}", bagdir.display()));
    // A rosbag2 directory with one .mcap is read as that file.
    let mcapdir = dir.path().join("rosbag2_mcap");
    std::fs::create_dir(&mcapdir).expect("mkdir");
    write_bag(&mcapdir.join("rosbag2_mcap_0.mcap"), true, &all_topics());
    let t = read_topic(&mcapdir, "/fix", &["latitude"], TimeSource::HeaderStamp).expect("dir");
    assert_eq!(t.t_s.len(), 10);
    // ... and with two, it is an error naming them.
    write_bag(&mcapdir.join("rosbag2_mcap_1.mcap"), true, &all_topics());
    assert_eq!(
        err(&mcapdir, "/fix", &[]),
        format!(
            "{}: a split bag of 2 .mcap files (rosbag2_mcap_0.mcap, rosbag2_mcap_1.mcap); odocal reads one file at a \
             time: give one of them",
            mcapdir.display()
        )
    );
    // Not MCAP at all.
    let csv = dir.path().join("drive.csv");
    std::fs::write(&csv, "t,x\n0,1\n").expect("write");
    assert_eq!(
        err(&csv, "/j", &[]),
        format!("{}: not an MCAP file (it does not start with the MCAP magic bytes)", csv.display())
    );
    // Missing.
    let missing = dir.path().join("missing.mcap");
    assert!(err(&missing, "/j", &[]).starts_with(&format!("{}: ", missing.display())));
    // Truncated in the middle of a chunk: an error, for inspect too.
    let full = test_bag(&dir, "zstd", true);
    let bytes = std::fs::read(&full).expect("read");
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).expect("write");
    let e = err(&cut, "/joints", &["position.left"]);
    let cut_message = format!("{}: truncated MCAP file: it ends after {} bytes", cut.display(), bytes.len() / 2);
    assert!(e.starts_with(&cut_message) && e.contains("the chunk record (opcode 0x06) at byte offset "), "{e}");
    assert_eq!(inspect(&cut).expect_err("truncated").to_string(), e);
}

/// A real bag cut at any byte — in a chunk, between two records, just
/// before the closing magic — is refused saying that it ends before its
/// footer, where the read stopped, and what to do: recover it with the
/// mcap CLI, or copy or record it again.
#[test]
fn a_bag_cut_anywhere_names_the_cut_and_the_way_out() {
    let slice = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/psu-mapping-van/drive-slice.mcap");
    let bytes = std::fs::read(&slice).expect("the PSU bag slice");
    let dir = tempfile::tempdir().expect("tempdir");
    let cut = dir.path().join("cut.mcap");
    // 247_215: the first chunk (at byte 43, 9 + 247_163 bytes) ends there
    // and a message index record starts: a cut between two records.
    for (at, stop) in [
        (5_000, Some("the chunk record (opcode 0x06) at byte offset 43 declares 247163 bytes, but only 4948 remain")),
        (247_215, None),
        (bytes.len() - 8, None),
        (bytes.len() - 1, None),
    ] {
        std::fs::write(&cut, &bytes[..at]).expect("write");
        let e = inspect(&cut).expect_err("a cut bag").to_string();
        let head = format!(
            "{}: truncated MCAP file: it ends after {at} bytes without the footer and closing magic bytes that end \
             every MCAP file",
            cut.display()
        );
        assert!(e.starts_with(&head), "cut at {at}: {e}");
        assert!(e.contains(&format!("`mcap recover {} -o recovered.mcap`", cut.display())), "{e}");
        assert!(e.ends_with("or copy or record the drive again"), "{e}");
        if let Some(stop) = stop {
            assert!(e.contains(&format!("every MCAP file ({stop} in the file).")), "{e}");
        }
        let read =
            read_topic(&cut, "/vehicle/wheel_joint_states", &["position.rear_left_wheel_joint"], TimeSource::LogTime);
        assert_eq!(read.expect_err("a cut bag").to_string(), e, "reading a topic says the same");
    }
    // The whole bag still reads.
    assert!(inspect(&slice).is_ok());
}

#[test]
fn inspect_lists_topics_counts_rates_and_compression() {
    let dir = tempfile::tempdir().expect("tempdir");
    for label in COMPRESSIONS {
        let p = test_bag(&dir, label, true);
        let info = inspect(&p).expect("inspect");
        assert_eq!(info.profile, "ros2");
        assert_eq!(info.compression.as_deref(), Some(&[label.to_string()][..]));
        assert_eq!(info.message_count, 50 + 3 * 20 + 10 + 10 + 1);
        let joints = info.topics.iter().find(|t| t.topic == "/joints").expect("joints");
        assert_eq!(joints.count, 50);
        assert_eq!((joints.first_log_time_ns, joints.last_log_time_ns), (Some(5_000), Some(490_005_000)));
        approx::assert_relative_eq!(joints.rate_hz().expect("rate"), 100.0, max_relative = 1e-12);
        assert_eq!(joints.supported_type, Some(MessageType::JointState));
        let chatter = info.topics.iter().find(|t| t.topic == "/chatter").expect("chatter");
        assert_eq!((chatter.supported_type, chatter.rate_hz()), (None, None));
        let text = info.to_string();
        assert!(text.contains("Topic: /chatter      | Type: std_msgs/msg/String                         | Count:  1 | Rate:         - | Serialization Format: cdr (odocal cannot read this type)"), "{text}");
        assert!(text.contains(&format!("Compression:       {label} (")), "{text}");
    }
    // No summary: the compression is unknown, the counts are still there.
    let p = test_bag(&dir, "lz4", false);
    let info = inspect(&p).expect("inspect");
    assert_eq!((info.compression.clone(), info.chunk_count, info.message_count), (None, None, 131));
    assert!(info.to_string().contains("Compression:       unknown (no summary section)"));
    // The columns a manifest can take: readable topics only, with the joints.
    let cols = info.manifest_columns().expect("columns");
    assert!(cols.starts_with("Manifest columns (format = \"mcap\", topic = ...):\n  /"), "{cols}");
    assert!(
        cols.contains(&format!("  /joints: {}\n    joints: ", MessageType::JointState.columns().join(", "))),
        "{cols}"
    );
    assert!(!cols.contains("/chatter"), "{cols}");
    let unreadable =
        BagInfo { topics: info.topics.into_iter().filter(|t| t.supported_type.is_none()).collect(), ..info };
    assert_eq!(unreadable.manifest_columns().expect("none"), "");
}

/// Encoded messages of every supported type, for the fuzz-ish tests.
fn samples() -> Vec<(MessageType, Vec<u8>)> {
    let mut out = Vec::new();
    for t in all_topics() {
        if let Some(ty) = MessageType::from_ros_name(t.ty) {
            out.push((ty, t.messages[1].1.clone()));
        }
    }
    assert_eq!(out.len(), 6);
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Truncated or mutated CDR decodes to `Err` or to some value, never a panic;
    /// the untouched message decodes.
    #[test]
    fn malformed_cdr_never_panics(which in 0usize..6, cut in 0usize..2000, flips in proptest::collection::vec((0usize..2000, any::<u8>()), 0..8)) {
        let s = samples();
        let (ty, data) = &s[which];
        prop_assert!(columns::decode(*ty, data).is_ok());
        let mut d = data.clone();
        for (i, b) in flips {
            let n = d.len();
            d[i % n] = b;
        }
        d.truncate(cut.min(d.len()));
        let _ = columns::decode(*ty, &d);
    }
}

/// The damaged bag on which mcap 0.26's reader panicked (an overflow in an
/// uncompressed chunk, debug builds) gives an error, not a panic. Found by
/// `damaged_bag_files_never_panic` (comp 0, no cut, byte at 0.1423 set to 3).
#[test]
fn bag_that_made_the_mcap_reader_overflow_gives_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("b.mcap");
    write_bag(&p, true, &all_topics());
    let mut bytes = std::fs::read(&p).expect("read");
    let n = bytes.len();
    bytes[((0.14230484594650797 * n as f64) as usize).min(n - 1)] = 3;
    std::fs::write(&p, &bytes).expect("write");
    for r in [
        read_topic(&p, "/joints", &["position.left"], TimeSource::HeaderStamp).map(|_| ()),
        read_topic(&p, "/fix", &[], TimeSource::LogTime).map(|_| ()),
    ] {
        if let Err(e) = r {
            assert!(e.to_string().contains("MCAP"), "{e}");
        }
    }
    let _ = inspect(&p);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// A bag file with bytes changed or cut is read without panicking (an
    /// error, or rows when the damage missed what matters).
    #[test]
    fn damaged_bag_files_never_panic(comp in 0usize..3, cut in 0.0f64..1.0, flips in proptest::collection::vec((0.0f64..1.0, any::<u8>()), 1..6)) {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("b.mcap");
        let mut bytes = std::fs::read(test_bag(&dir, COMPRESSIONS[comp], true)).expect("read");
        let n = bytes.len();
        for (at, b) in flips {
            bytes[((at * n as f64) as usize).min(n - 1)] = b;
        }
        if cut > 0.5 {
            bytes.truncate((cut * n as f64) as usize);
        }
        std::fs::write(&p, &bytes).expect("write");
        let _ = read_topic(&p, "/joints", &["position.left"], TimeSource::HeaderStamp);
        let _ = read_topic(&p, "/fix", &[], TimeSource::LogTime);
        let _ = inspect(&p);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    /// The length-checking `JointState` decoder reads what the serde CDR
    /// decoder reads, on valid messages and on damaged ones: where serde
    /// decodes, it decodes to the same values.
    #[test]
    fn joint_decoder_agrees_with_serde(
        n in 0usize..5,
        extra in 0usize..3,
        effort in 0usize..3,
        frame in "[a-z]{0,7}",
        big_endian in any::<bool>(),
        cut in 0usize..400,
        flips in proptest::collection::vec((0usize..400, any::<u8>()), 0..4),
    ) {
        let m = msg::JointState {
            header: header(T0, 123_456_789, &frame),
            name: (0..n).map(|i| "j".repeat(i + 1)).collect(),
            position: (0..n + extra).map(|i| i as f64 * 0.5 - 1.0).collect(),
            velocity: (0..n).map(|i| -(i as f64)).collect(),
            effort: vec![2.5; effort],
        };
        let mut data = if big_endian {
            let mut out = vec![0x00, 0x00, 0x00, 0x00];
            out.extend(cdr_encoding::to_vec::<_, byteorder::BigEndian>(&m).expect("encode"));
            out
        } else {
            encode(&m)
        };
        let j = msg::decode_joints(&data).expect("valid message");
        prop_assert_eq!(j.stamp, m.header.stamp);
        prop_assert_eq!(&j.name, &m.name.iter().map(String::as_str).collect::<Vec<_>>());
        prop_assert_eq!(bits(&j.position), bits(&m.position));
        prop_assert_eq!(bits(&j.velocity), bits(&m.velocity));
        for (i, b) in flips {
            let len = data.len();
            data[i % len] = b;
        }
        data.truncate(cut.min(data.len()));
        if let Ok(s) = msg::decode::<msg::JointState>(&data) {
            let j = msg::decode_joints(&data).expect("serde decoded it");
            prop_assert_eq!(&j.name, &s.name.iter().map(String::as_str).collect::<Vec<_>>());
            prop_assert_eq!(bits(&j.position), bits(&s.position));
            prop_assert_eq!(bits(&j.velocity), bits(&s.velocity));
        }
    }
}

/// A `JointState` whose arrays declare 2³¹ elements is refused, naming the
/// array, before anything is allocated for it; so is one naming more joints
/// than odocal reads.
#[test]
fn joint_arrays_declaring_more_than_the_message_holds_are_refused() {
    let m = msg::JointState {
        header: header(T0, 0, "b"),
        name: vec!["a".into()],
        position: vec![1.0],
        velocity: vec![2.0],
        effort: vec![],
    };
    let good = encode(&m);
    // The name count follows the header: 4 (encapsulation) + 8 (stamp) + 4 + 2 ("b\0"), padded to 20.
    let mut bad = good.clone();
    bad[20..24].copy_from_slice(&(1u32 << 31).to_le_bytes());
    let e = msg::decode_joints(&bad).expect_err("huge name array");
    assert!(e.contains("its name array declares 2147483648 elements, more than the"), "{e}");
    let many = msg::JointState { name: vec![String::new(); msg::MAX_JOINTS + 1], ..m };
    let e = msg::decode_joints(&encode(&many)).expect_err("too many joints");
    assert!(e.contains("its name array has 65537 elements; odocal reads at most 65536 joints per message"), "{e}");
}

/// Header stamps with `nanosec` ≥ 10⁹ and a header clock stepping back are
/// errors naming the topic, the message and the step; messages out of order
/// by less are sorted (`rows_are_sorted_by_the_chosen_time`).
#[test]
fn invalid_nanosec_and_a_clock_stepping_back_are_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mk = |sec: i32, nanosec: u32| {
        encode(&msg::PoseStamped { header: header(sec, nanosec, "map"), pose: msg::Pose::default() })
    };
    let cases = [
        (
            "nanosec.mcap",
            vec![(1, mk(5, 0)), (2, mk(5, 2_000_000_000))],
            "topic '/p': message 1 (log time 0.000000002 s) has header.stamp.nanosec = 2000000000, not below 10^9 \
             (sec = 5)",
        ),
        (
            "step.mcap",
            vec![(1, mk(100, 0)), (2, mk(100, 500_000_000)), (3, mk(90, 0))],
            "topic '/p': the header clock steps back 10.5 s at message 2 (log time 0.000000003 s): its stamp 90 s is \
             before message 1's 100.5 s",
        ),
    ];
    for (name, messages, want) in cases {
        let p = dir.path().join(name);
        write_bag(&p, true, &[Topic { name: "/p", ty: "geometry_msgs/msg/PoseStamped", encoding: "cdr", messages }]);
        let e = err(&p, "/p", &["x"]);
        assert!(e.contains(want) && e.contains("time = \"log\""), "{e}");
        read_topic(&p, "/p", &["x"], TimeSource::LogTime).expect("the log time is fine");
    }
}

/// MCAP lengths larger than what remains (a record longer than the file, a
/// topic name longer than its record, a record longer than its chunk) are
/// errors naming the record and its offset, found before any allocation.
#[test]
fn mcap_lengths_larger_than_what_remains_are_named() {
    fn rec(op: u8, body: &[u8], declared: Option<u64>) -> Vec<u8> {
        let mut r = vec![op];
        r.extend(declared.unwrap_or(body.len() as u64).to_le_bytes());
        r.extend(body);
        r
    }
    fn string(s: &str, declared: Option<u32>) -> Vec<u8> {
        let mut r = declared.unwrap_or(s.len() as u32).to_le_bytes().to_vec();
        r.extend(s.as_bytes());
        r
    }
    let schema = rec(
        0x03,
        &[
            &1u16.to_le_bytes()[..],
            &string("geometry_msgs/msg/PoseStamped", None),
            &string("ros2msg", None),
            &0u32.to_le_bytes(),
        ]
        .concat(),
        None,
    );
    let channel = |topic_len: Option<u32>, rec_len: Option<u64>| {
        rec(
            0x04,
            &[&[1, 0, 1, 0][..], &string("/p", topic_len), &string("cdr", None), &0u32.to_le_bytes()].concat(),
            rec_len,
        )
    };
    let file = |records: &[Vec<u8>]| {
        let mut f = mcap::MAGIC.to_vec();
        f.extend(rec(0x01, &[string("ros2", None), string("x", None)].concat(), None));
        for r in records {
            f.extend(r);
        }
        f.extend(rec(0x0F, &0u32.to_le_bytes(), None));
        f.extend(rec(0x02, &[0u8; 20], None));
        f.extend(mcap::MAGIC);
        f
    };
    let chunk = |records: Vec<u8>| {
        let body = [
            &[0u8; 16][..],
            &(records.len() as u64).to_le_bytes(),
            &0u32.to_le_bytes(),
            &string("", None),
            &(records.len() as u64).to_le_bytes(),
            &records,
        ]
        .concat();
        rec(0x06, &body, None)
    };
    let message = rec(0x05, &[0u8; 22], Some(200 << 20));
    let cases = [
        (file(&[schema.clone(), channel(Some(u32::MAX), None)]), "the channel record at byte offset 89 declares a topic name of 4294967295 bytes, but only 13 remain in the record"),
        (file(&[schema.clone(), channel(None, Some(1 << 32))]), "the channel record (opcode 0x04) at byte offset 89 declares 4294967296 bytes, but only"),
        (file(&[chunk([schema.clone(), channel(None, None), message].concat())]), "the message record (opcode 0x05) at byte offset 168 declares 209715200 bytes, but only 22 remain in its chunk (at byte offset 30)"),
    ];
    let dir = tempfile::tempdir().expect("tempdir");
    for (i, (bytes, want)) in cases.iter().enumerate() {
        let p = dir.path().join(format!("{i}.mcap"));
        std::fs::write(&p, bytes).expect("write");
        for e in [inspect(&p).map(|_| ()), read_topic(&p, "/p", &["x"], TimeSource::HeaderStamp).map(|_| ())] {
            let e = e.expect_err("hostile lengths").to_string();
            assert!(e.contains(&format!("{i}.mcap: corrupt")) && e.contains(want), "{e}");
        }
    }
}
