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
        &["--threads", "100000 is above the ceiling of 1024"],
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

/// A file name with a control character, echoed in an error, is escaped
/// as the names read from files are.
#[test]
fn control_characters_in_a_path_are_escaped_in_the_error() {
    let dir = tempfile::tempdir().expect("tmp");
    let missing = dir.path().join("d\u{1b}[31m.csv");
    let o = odocal(&["calibrate", s(&missing)]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(!e.contains('\u{1b}') && e.contains("d\\u{1b}[31m.csv"), "{e}");
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

/// An MCAP record: opcode, declared length (`None`: the body's), body.
pub(crate) fn mcap_record(op: u8, body: &[u8], declared: Option<u64>) -> Vec<u8> {
    let mut r = vec![op];
    r.extend(declared.unwrap_or(body.len() as u64).to_le_bytes());
    r.extend(body);
    r
}

/// An MCAP string: `uint32` length (declared, or the real one), bytes.
pub(crate) fn mcap_string(s: &str, declared: Option<u32>) -> Vec<u8> {
    let mut r = declared.unwrap_or(s.len() as u32).to_le_bytes().to_vec();
    r.extend(s.as_bytes());
    r
}

/// An unchunked MCAP file: magic, header, a JointState schema, the channel
/// `/j` (its topic length declared as `topic_len`), the `messages`, data
/// end, footer, magic.
pub(crate) fn mcap_file(topic_len: Option<u32>, messages: &[Vec<u8>]) -> Vec<u8> {
    let mut f = b"\x89MCAP0\r\n".to_vec();
    f.extend(mcap_record(0x01, &[mcap_string("ros2", None), mcap_string("", None)].concat(), None));
    let schema = [
        &1u16.to_le_bytes()[..],
        &mcap_string("sensor_msgs/msg/JointState", None),
        &mcap_string("ros2msg", None),
        &[0; 4],
    ];
    f.extend(mcap_record(0x03, &schema.concat(), None));
    let channel = [&[1, 0, 1, 0][..], &mcap_string("/j", topic_len), &mcap_string("cdr", None), &[0; 4]];
    f.extend(mcap_record(0x04, &channel.concat(), None));
    for (i, data) in messages.iter().enumerate() {
        let t = 1_000_000_000 + i as u64 * 10_000_000;
        let head = [&1u16.to_le_bytes()[..], &0u32.to_le_bytes(), &t.to_le_bytes(), &t.to_le_bytes()].concat();
        f.extend(mcap_record(0x05, &[head, data.clone()].concat(), None));
    }
    f.extend(mcap_record(0x0F, &[0; 4], None));
    f.extend(mcap_record(0x02, &[0; 20], None));
    f.extend(b"\x89MCAP0\r\n");
    f
}

/// A 173-byte MCAP whose topic name declares 4 GiB, and a 778 KiB one of
/// JointState messages whose arrays declare 2³¹ elements: `inspect` and
/// `import` end in an error naming the record or the array, within 1 GB.
#[test]
fn mcap_lengths_beyond_the_bytes_left_are_refused_before_allocating() {
    let dir = tempfile::tempdir().expect("tmp");
    let topic = dir.path().join("topic.mcap");
    std::fs::write(&topic, mcap_file(Some(u32::MAX), &[])).expect("write");
    let want = "the channel record at byte offset 85 declares a topic name of 4294967295 bytes, but only 13 remain";
    refused_within_1gb(&["inspect", s(&topic)], &["topic.mcap: corrupt MCAP file", want]);

    // Each message: CDR header, a stamp, frame "b", then one array of
    // name/position/velocity/effort declaring 2^31 elements, the others one.
    let messages: Vec<Vec<u8>> = (0..6000u32)
        .map(|i| {
            let mut counts = [1u32; 4];
            counts[(i % 4) as usize] = 1 << 31;
            let mut b = vec![0, 1, 0, 0];
            b.extend(100i32.to_le_bytes());
            b.extend((i * 1000).to_le_bytes());
            b.extend(2u32.to_le_bytes());
            b.extend(b"b\0\0\0");
            b.extend(counts[0].to_le_bytes());
            b.extend(2u32.to_le_bytes());
            b.extend(b"a\0\0\0");
            for c in &counts[1..] {
                b.extend(c.to_le_bytes());
                b.extend([0; 4]);
                b.extend(0.5f64.to_le_bytes());
            }
            b.extend([0; 32]);
            b
        })
        .collect();
    let joints = dir.path().join("joints.mcap");
    let bytes = mcap_file(None, &messages);
    assert!(bytes.len() > 700 << 10, "{}", bytes.len());
    std::fs::write(&joints, bytes).expect("write");
    let array = "message 0 (log time 1.000000000 s) is not a sensor_msgs/msg/JointState: its name array declares \
                 2147483648 elements, more than the";
    refused_within_1gb(&["inspect", s(&joints)], &["joints.mcap: topic '/j'", array]);
    let m = dir.path().join("m.toml");
    let slice = Path::new(env!("CARGO_MANIFEST_DIR")).join("../odocal/tests/data/psu-mapping-van/drive-slice.mcap");
    let manifest = format!(
        "[streams.wheels]\nformat = \"mcap\"\nfile = \"joints.mcap\"\ntopic = \"/j\"\n\n[streams.pose]\n\
         format = \"mcap\"\nfile = \"{}\"\ntopic = \"/localization/pose_with_covariance\"\n\n[wheels]\n\
         stream = \"wheels\"\nsignal = \"rad_cumulative\"\nrear_left = {{ column = \"position.a\" }}\n\
         rear_right = {{ column = \"position.a\" }}\n\n[pose]\nstream = \"pose\"\n\
         position = {{ kind = \"local\", x = \"x\", y = \"y\" }}\n",
        slice.display()
    );
    std::fs::write(&m, manifest).expect("write");
    refused_within_1gb(&["import", s(&m), "--out", s(&dir.path().join("o.csv"))], &["joints.mcap", array]);
}
