//! A careless input never gives an accepted wrong answer: a lateral
//! acceleration with the wrong sign or unit, a clock offset at the edge of
//! its search, a damaged MCAP chunk, an absurd parameter file and a drive
//! whose wheel signs are negated are each refused with the fix.

use std::path::{Path, PathBuf};

use crate::common::{odocal, simulated_drive, stderr};

fn s(p: &Path) -> &str {
    p.to_str().expect("utf8")
}

/// Runs odocal, asserting it fails (exit 1) with a message containing each of `needles`.
fn refused(args: &[&str], needles: &[&str]) -> String {
    refused_with(1, args, needles)
}

/// As [`refused`], with the exit code `code` (2: a bad command line).
fn refused_with(code: i32, args: &[&str], needles: &[&str]) -> String {
    let o = odocal(args);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(code), "{args:?} was not refused: {e}");
    for n in needles {
        assert!(e.contains(n), "{args:?}: '{n}' not in: {e}");
    }
    e
}

/// The drive CSV at `src` written to `dst` with column `name` mapped by `f`.
fn edit_column(src: &Path, dst: &Path, name: &str, f: impl Fn(f64) -> f64) {
    let text = std::fs::read_to_string(src).expect("drive");
    let mut lines = text.lines();
    let header = lines.next().expect("header");
    let col = header.split(',').position(|c| c == name).expect("column");
    let mut out = format!("{header}\n");
    for l in lines {
        let mut cells: Vec<String> = l.split(',').map(str::to_owned).collect();
        let v: f64 = cells[col].parse().expect("number");
        cells[col] = format!("{}", f(v));
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    std::fs::write(dst, out).expect("write");
}

#[test]
fn lateral_acceleration_of_the_wrong_sign_or_unit_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = PathBuf::from(simulated_drive(dir.path(), "d.csv", &["--length-km", "3"]));
    let (neg, feet) = (dir.path().join("neg.csv"), dir.path().join("feet.csv"));
    edit_column(&d, &neg, "a_y", |v| -v);
    edit_column(&d, &feet, "a_y", |v| v / 0.3048);
    let theta = ["--theta", "2,0,1.6,0"];
    assert!(
        odocal(&["validate", s(&d), theta[0], theta[1], "--no-drive-fit"]).status.success(),
        "the simulated drive is accepted"
    );
    for p in [&neg, &feet] {
        let (sign, unit) =
            (["wrong sign", "negate column 'a_y'"], ["ft/s² gives 3.28", "convert column 'a_y' to m/s²"]);
        let [why, fix] = if p == &neg { sign } else { unit };
        // The message names the file, not "drive".
        let file = format!("error: {}: ", s(p));
        refused(&["calibrate", s(p)], &[why, fix, &file]);
        refused(&["validate", s(p), theta[0], theta[1]], &[why, fix, &file]);
    }
}

#[test]
fn an_imu_lateral_acceleration_of_the_wrong_sign_names_the_key() {
    let dir = tempfile::tempdir().expect("tmp");
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../odocal/tests/data/comma2k19-rav4");
    for e in std::fs::read_dir(&src).expect("rav4 slice") {
        let e = e.expect("entry");
        std::fs::copy(e.path(), dir.path().join(e.file_name())).expect("copy");
    }
    let m = dir.path().join("manifest.toml");
    let text = std::fs::read_to_string(&m).expect("manifest");
    assert!(odocal(&["import", s(&m), "--out", s(&dir.path().join("ok.csv"))]).status.success());
    std::fs::write(&m, text.replace("sign = -1", "sign = 1")).expect("write");
    refused(
        &["import", s(&m), "--out", s(&dir.path().join("x.csv"))],
        &["lateral_acceleration.sign", "wrong sign", "the column 'a_right_mps2' of stream 'imu'", "sign = -1"],
    );
}

#[test]
fn a_clock_offset_at_the_edge_of_its_search_is_searched_wider_or_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../odocal/tests/data/psu-mapping-van");
    for e in std::fs::read_dir(&src).expect("van slice") {
        let e = e.expect("entry");
        std::fs::copy(e.path(), dir.path().join(e.file_name())).expect("copy");
    }
    let text = std::fs::read_to_string(dir.path().join("manifest.toml")).expect("manifest");
    assert!(text.contains("time_offset_s = 0.105"));
    let shifted = |off: &str| {
        let m = dir.path().join(format!("m{off}.toml"));
        std::fs::write(&m, text.replace("time_offset_s = 0.105", &format!("time_offset_s = {off}"))).expect("write");
        m
    };
    // The pose 3 s early: the ±2 s search ends at its edge; ±10 s finds it.
    let m = shifted("-2.895");
    let o = odocal(&["import", s(&m), "--out", s(&dir.path().join("a.csv"))]);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(e.contains("lay at the edge of the search (±2 s), so ±10 s was searched: +3.07"), "{e}");
    // 15 s off: at the edge of ±10 s too.
    refused(
        &["import", s(&shifted("15.105")), "--out", s(&dir.path().join("b.csv"))],
        &["output.clock_offset", "\"auto\" found no clock offset", "at the edge", "Set output.clock_offset"],
    );
}

#[test]
fn a_damaged_mcap_chunk_is_an_error_naming_it() {
    let dir = tempfile::tempdir().expect("tmp");
    let bag = dir.path().join("b.mcap");
    let mut w = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(None)
        .create(std::io::BufWriter::new(std::fs::File::create(&bag).expect("create")))
        .expect("writer");
    let schema = w.add_schema("std_msgs/msg/String", "ros2msg", b"string data").expect("schema");
    let ch = w.add_channel(schema, "/t", "cdr", &Default::default()).expect("channel");
    for k in 0..20u64 {
        let h = mcap::records::MessageHeader { channel_id: ch, sequence: k as u32, log_time: k, publish_time: k };
        w.write_to_known_channel(&h, b"\x00\x01\x00\x00\x0b\x00\x00\x00MARKERBYTE\x00").expect("write");
    }
    w.finish().expect("finish");
    drop(w);
    assert!(odocal(&["inspect", s(&bag)]).status.success(), "the intact bag reads");
    let mut bytes = std::fs::read(&bag).expect("bag");
    let at = bytes.windows(10).position(|w| w == b"MARKERBYTE").expect("marker");
    bytes[at] ^= 0x04;
    std::fs::write(&bag, &bytes).expect("write");
    refused(&["inspect", s(&bag)], &["fails its CRC check", "chunk 1 of 1 (byte offset"]);
}

#[test]
fn a_chunk_declaring_no_uncompressed_bytes_is_an_error() {
    let dir = tempfile::tempdir().expect("tmp");
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../odocal/tests/data/psu-mapping-van/drive-slice.mcap");
    let mut b = std::fs::read(src).expect("slice");
    // The second chunk record: skip the magic and the records before it.
    let mut pos = 8;
    let mut chunks = 0;
    while chunks < 2 {
        let len = u64::from_le_bytes(b[pos + 1..pos + 9].try_into().expect("8 bytes")) as usize;
        if b[pos] == 0x06 {
            chunks += 1;
            if chunks == 2 {
                break;
            }
        }
        pos += 9 + len;
    }
    // Chunk body: start time, end time, then the uncompressed size.
    b[pos + 9 + 16..pos + 9 + 24].fill(0);
    let bag = dir.path().join("zero.mcap");
    std::fs::write(&bag, &b).expect("write");
    refused(
        &["inspect", s(&bag)],
        &["corrupt MCAP file: the chunk at byte offset", "decompresses to more than the 0 bytes it declares"],
    );
}

/// A ROS 2 parameter file of the nodes `(name, extra lines)`, θ the paper's θ_0.
fn param_file(nodes: &[(&str, &str)]) -> String {
    nodes
        .iter()
        .map(|(n, extra)| {
            format!("{n}:\n  ros__parameters:\n    c_e: 2.0\n    c_d: 0.0\n    t_r: 1.6\n    d: 0.0\n{extra}")
        })
        .collect()
}

#[test]
fn parameter_files_get_the_plausibility_checks_and_must_name_one_node() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).expect("write");
        p.to_str().expect("utf8").to_owned()
    };
    let ok = write("ok.yaml", &param_file(&[("odocal", "")]));
    assert!(odocal(&["validate", &d, "--theta", &ok, "--no-drive-fit"]).status.success());
    let lever = write("lever.yaml", &param_file(&[("odocal", "    lever_x: 1.0e300\n")]));
    refused_with(2, &["validate", &d, "--theta", &lever], &["lever.yaml", "key `lever_x`", "within ±20 m"]);
    let heading = write("heading.yaml", &param_file(&[("odocal", "    heading_offset: 1000.0\n")]));
    refused_with(2, &["validate", &d, "--theta", &heading], &["key `heading_offset`", "within ±π rad"]);
    let two = write("two.yaml", &param_file(&[("a", ""), ("b", "    lever_x: 0.5\n")]));
    refused_with(
        2,
        &["validate", &d, "--theta", &two],
        &["several nodes hold odocal's parameters (a, b)", "--params-node"],
    );
    let o = odocal(&["validate", &d, "--theta", &two, "--params-node", "b", "--no-drive-fit"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(crate::common::stdout(&o).contains("lever arm = [0.5000, 0.0000] m"), "{}", crate::common::stdout(&o));
    refused_with(2, &["validate", &d, "--theta", &two, "--params-node", "c"], &["no node `c` (nodes: a, b)"]);
    let docs = write("docs.yaml", &format!("{}---\n{}", param_file(&[("odocal", "")]), param_file(&[("odocal", "")])));
    refused_with(2, &["validate", &d, "--theta", &docs], &["2 YAML documents"]);
    refused_with(2, &["calibrate", &d, "--theta0", &two], &["several nodes", "--theta0-node"]);
}

#[test]
fn a_manifest_theta0_and_clock_offset_are_checked_like_the_command_line() {
    let dir = tempfile::tempdir().expect("tmp");
    simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]);
    let m = dir.path().join("m.toml");
    let base = crate::common::canonical_manifest("d.csv", "");
    let out = dir.path().join("x.csv");
    std::fs::write(&m, base.replace("[output]\n", "[output]\ntheta0 = [2000.0, 0.0, 1.6, 0.0]\n")).expect("write");
    refused(&["import", s(&m), "--out", s(&out)], &["output.theta0", "c_e = 2000 m is outside"]);
    std::fs::write(&m, base.replace("clock_offset = 0.0", "clock_offset = 1e9")).expect("write");
    refused(&["import", s(&m), "--out", s(&out)], &["output.clock_offset", "above the limit of 60"]);
    std::fs::write(&m, base + "\n[calibration]\ntheta0 = [2.0, 5.0, 1.6, 0.0]\n").expect("write");
    refused(&["calibrate", s(&m)], &["theta0", "c_d", "SI units"]);
}

#[test]
fn validate_refuses_negated_wheel_signs_as_calibrate_does() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = PathBuf::from(simulated_drive(dir.path(), "d.csv", &["--length-km", "2"]));
    let (one, both) = (dir.path().join("one.csv"), dir.path().join("both.csv"));
    edit_column(&d, &one, "n_rl", |v| -v);
    edit_column(&one, &both, "n_rr", |v| -v);
    refused(
        &["validate", s(&both), "--theta", "2,0,1.6,0"],
        &["the wheels turn backwards", "flip the sign of n_rl and n_rr"],
    );
    refused(&["calibrate", s(&both)], &["the wheels turn backwards"]);
}

/// c_e, c_d and d are per model revolution, which a manifest defines (e.g.
/// `ticks_per_rev`): drives that count revolutions otherwise are refused as
/// one calibration, as its validation drives and as drives followed
/// together, a parameter file records its scale, and `validate` with it on
/// such a drive warns.
#[test]
fn drives_that_count_wheel_revolutions_otherwise_are_not_mixed() {
    let dir = tempfile::tempdir().expect("tmp");
    let root = format!("{}/../..", env!("CARGO_MANIFEST_DIR"));
    let e = format!("{root}/examples/psu-mapping-van-testtrack");
    let own = format!("{e}/run-14-45-26.toml");
    let text = std::fs::read_to_string(format!("{e}/run-15-28-33.toml")).expect("manifest");
    assert!(text.contains("ticks_per_rev = 40460.0"), "the shipped scale");
    let other = dir.path().join("other.toml");
    std::fs::write(
        &other,
        text.replace("\"../../data", &format!("\"{root}/data"))
            .replace("ticks_per_rev = 40460.0", "ticks_per_rev = 40360.0"),
    )
    .expect("write");
    let needles = ["count wheel revolutions differently", "40460 ticks", "40360 ticks", "ticks_per_rev"];
    refused(&["calibrate", &own, s(&other)], &needles);
    refused(&["calibrate", &own, "--validate-on", s(&other)], &["judged in another unit", "40360 ticks"]);
    // A CSV states no scale; the --validate-on drives must still agree with each other.
    let csv = dir.path().join("own.csv");
    let o = odocal(&["import", &own, "--out", s(&csv)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let both = format!("{e}/run-16-06-28.toml,{}", s(&other));
    refused(&["calibrate", s(&csv), "--validate-on", &both], &["judged in another unit", "40360 ticks"]);
    // Followed as one vehicle: refused at the drive that differs.
    let db = dir.path().join("v.sqlite");
    refused(
        &["follow", &own, s(&other), "--vehicle", "van", "--db", s(&db)],
        &["cannot follow drives that count wheel revolutions differently", "40360 ticks"],
    );
    // What follow writes carries its scale too.
    let followed = dir.path().join("f.yaml");
    let fresh = dir.path().join("f.sqlite");
    let o = odocal(&["follow", &own, "--vehicle", "van", "--db", s(&fresh), "--params-out", s(&followed)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let file = std::fs::read_to_string(&followed).expect("follow wrote an update");
    assert!(file.contains("wheel_scale: \"ticks, one model revolution = ticks_per_rev = 40460 ticks"), "{file}");
    let params = dir.path().join("p.yaml");
    let o = odocal(&["calibrate", &own, "--params-out", s(&params)]);
    assert!(o.status.code() != Some(1), "{}", stderr(&o));
    let file = std::fs::read_to_string(&params).expect("params");
    assert!(file.contains("wheel_scale: \"ticks, one model revolution = ticks_per_rev = 40460 ticks"), "{file}");
    // An update written at a drive CSV (which states no scale) after a
    // manifest's rests on both: it carries the manifest's scale.
    let later = dir.path().join("later.csv");
    let o = odocal(&["import", &format!("{e}/run-16-06-28.toml"), "--out", s(&later)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let both_db = dir.path().join("both.sqlite");
    let o = odocal(&["follow", &own, s(&later), "--vehicle", "van", "--db", s(&both_db), "--params-out", s(&followed)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let file = std::fs::read_to_string(&followed).expect("follow wrote an update");
    assert!(file.contains("later.csv") && file.contains("ticks_per_rev = 40460 ticks"), "{file}");
    // follow from θ_0 in a parameter file of another scale: warned at the first drive.
    let db = dir.path().join("theta0.sqlite");
    let o = odocal(&["follow", s(&other), "--vehicle", "van", "--db", s(&db), "--theta0", s(&params)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("the recursion started from θ_0 as it stands"), "{}", stderr(&o));
    let warned = |drive: &str| {
        let o = odocal(&["validate", drive, "--theta", s(&params)]);
        assert!(o.status.code() != Some(1), "{}", stderr(&o));
        stderr(&o).contains("counts wheel revolutions as")
    };
    assert!(warned(s(&other)), "another scale is warned about");
    assert!(!warned(&format!("{e}/run-15-28-33.toml")), "the same scale is not");
}
