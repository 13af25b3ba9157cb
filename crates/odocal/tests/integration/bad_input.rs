//! Bad input never panics and never yields a confident wrong drive: the
//! committed corpus (every reproducer of the bad-input issue, minimised) is
//! replayed through the same harness the fuzz targets use (`fuzz/`), and
//! property tests mutate valid inputs.

use crate::common;

use std::path::{Path, PathBuf};

use common::harness::{self, Outcome};
use proptest::prelude::*;

fn corpus(kind: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus").join(kind);
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(&dir).expect("corpus folder").map(|e| e.expect("entry").path()).collect();
    files.sort();
    assert!(!files.is_empty(), "empty corpus {}", dir.display());
    files
}

fn message(o: &Outcome) -> &str {
    match o {
        Outcome::Error(m) => m,
        other => panic!("expected an error, got {other:?}"),
    }
}

/// Every CSV reproducer gives the error that names its cause (or is accepted
/// when it is valid).
#[test]
fn csv_reproducers_name_their_cause() {
    let expect: &[(&str, &[&str])] = &[
        ("bom_crlf.csv", &[]),
        ("duplicate_t.csv", &["line 1", "duplicate column name(s) t"]),
        ("empty.csv", &["the file is empty"]),
        ("fuzz_many_duplicates.csv", &["line 1: duplicate column name(s)", "more)"]),
        ("gzip.csv", &["gzip-compressed", "gunzip"]),
        ("header_only.csv", &["no data rows"]),
        ("heading_degrees.csv", &["line 3, column 'psi'", "degrees"]),
        ("heading_jump_pi.csv", &["line 102, column 'psi'", "jump"]),
        ("invalid_utf8.csv", &["line 22", "UTF-8"]),
        ("long_field.csv", &["line 102", "column 't'", "not finite", "… (5000 bytes)"]),
        ("long_header.csv", &["too few to infer the sample time"]),
        ("mcap_bag.csv", &["a ROS 2 bag (MCAP), not a canonical drive CSV", "odocal inspect", "manifest"]),
        ("parquet.csv", &["a Parquet file", "format = \"parquet\""]),
        ("part_float.csv", &["line 2, column 'part'", "not a non-negative integer"]),
        ("part_negative.csv", &["line 2, column 'part'", "not a non-negative integer"]),
        ("px_1e308.csv", &["column 'px'", "positions must be metres"]),
        ("ragged.csv", &["line 202", "3 fields, the header has 8"]),
        ("rosbag1.csv", &["a ROS 1 bag", "mcap convert"]),
        ("semicolon.csv", &["missing column(s)", "separated by ';' or tabs"]),
        ("sqlite_bag.csv", &["sqlite3 (.db3) bag", "ros2 bag convert"]),
        ("tab.csv", &["missing column(s)", "separated by ';' or tabs"]),
        ("text_extra.csv", &[]),
        ("time_100s.csv", &["sample time 1.000e2 s", "milliseconds"]),
        ("time_ns.csv", &["microseconds or nanoseconds"]),
        ("time_tiny.csv", &["outside the plausible"]),
        ("valid.csv", &[]),
        ("wheels_1e300.csv", &["line 2, column 'n_rl'", "rev/s"]),
    ];
    harness::replay(&corpus("csv_drive"), expect, harness::csv_drive);
}

/// A field that is not a number is echoed cut short; a 10 MB field and a
/// 1 MiB header are lines beyond the CSV line limit, refused with their
/// line and not echoed.
#[test]
fn huge_fields_are_not_echoed() {
    let big = "7".repeat(500_000);
    let csv = format!("t,px,py,psi,n_rl,n_rr,beta,a_y\n0,{big}x,0,0,0,0,0,0\n");
    let m = harness::csv_drive(csv.as_bytes());
    assert!(message(&m).contains("(500001 bytes)"), "{m:?}");
    let big = "7".repeat(10 << 20);
    let csv = format!("t,px,py,psi,n_rl,n_rr,beta,a_y\n0,{big}x,0,0,0,0,0,0\n");
    let m = harness::csv_drive(csv.as_bytes());
    assert!(message(&m).contains("line 2: the line is longer than 1 MiB"), "{m:?}");
    assert!(message(&m).len() < 300, "{m:?}");
    let header = format!("t,{},px\n", "h".repeat(1 << 20));
    let m = harness::csv_drive(header.as_bytes());
    assert!(message(&m).contains("line 1: the line is longer than 1 MiB"), "{m:?}");
    assert!(message(&m).len() < 300, "{m:?}");
}

#[test]
fn manifest_corpus_never_panics() {
    for path in corpus("manifest") {
        let o = harness::manifest(&std::fs::read(&path).expect("read"));
        if let Outcome::Error(m) = &o {
            assert_eq!(m.lines().count(), 1, "{}: {m}", path.display());
        }
    }
}

/// Tokens the mutations insert: the numbers and characters that break readers.
const TOKENS: [&str; 14] =
    ["nan", "inf", "-", ",", "\n", "\"", "1e308", "-1e308", "0", ";", "=", "[", "9223372036854775807", "1e-300"];

fn mutate(base: &str, ops: &[(u8, usize, usize)]) -> Vec<u8> {
    harness::mutate(base, ops, &TOKENS)
}

fn valid(kind: &str, name: &str) -> String {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus").join(kind).join(name);
    std::fs::read_to_string(p).expect("read valid corpus file")
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    /// A mutated valid drive CSV gives a clean error or a finite drive.
    #[test]
    fn mutated_csv_never_panics(ops in prop::collection::vec((any::<u8>(), any::<usize>(), any::<usize>()), 1..6)) {
        let data = mutate(&valid("csv_drive", "valid.csv"), &ops);
        let _ = harness::csv_drive(&data);
    }

    /// A mutated valid manifest gives a clean error or a parsed manifest.
    #[test]
    fn mutated_manifest_never_panics(ops in prop::collection::vec((any::<u8>(), any::<usize>(), any::<usize>()), 1..6)) {
        let text = valid("import", "valid.bundle");
        let m = text.split("=== m.toml\n").nth(1).and_then(|s| s.split("=== ").next()).unwrap_or("");
        let _ = harness::manifest(&mutate(m, &ops));
    }
}

/// Every bag reproducer (MCAP lengths beyond what remains, damaged chunks)
/// gives an error naming the record and its offset; the small valid bag
/// reads.
#[cfg(feature = "mcap")]
#[test]
fn bag_reproducers_name_their_cause() {
    let expect: &[(&str, &[&str])] = &[
        ("hostile_bigrec.mcap", &["the channel record (opcode 0x04) at byte offset 86 declares 209715200 bytes"]),
        ("hostile_channel_metadata.mcap", &["the channel record at byte offset", "has a string in its metadata"]),
        ("hostile_chunk_index.mcap", &["the chunk index record at byte offset 30 declares a message index offsets of 4 bytes, not a whole"]),
        ("hostile_chunk_index2.mcap", &["the chunk index record at byte offset 30 declares a message index offsets of 23 bytes, not a whole number of its 10-byte entries"]),
        ("hostile_chunk_tail.mcap", &["its chunk (at byte offset 30) ends with 6 byte(s) that are not a whole record"]),
        (
            "hostile_header.mcap",
            &["the header record at byte offset 8 declares a library of 4291060737 bytes, but only 0 remain"],
        ),
        ("hostile_inner.mcap", &["the message record (opcode 0x05) at byte offset 165 declares 209715200 bytes"]),
        (
            "hostile_innerz.mcap",
            &["the message record (opcode 0x05)", "declares 209715200 bytes", "decompressed records of the chunk"],
        ),
        ("hostile_record.mcap", &["the channel record (opcode 0x04) at byte offset 86 declares 4294967296 bytes"]),
        ("hostile_topic.mcap", &["the channel record at byte offset 86 declares a topic name of 4294967295 bytes"]),
        (
            "hostile_topicz.mcap",
            &["declares a topic name of 4294967280 bytes", "decompressed records of the chunk at byte offset 30"],
        ),
        (
            "hostile_unc.mcap",
            &["fuzz.mcap: corrupt MCAP file: the chunk at byte offset 30 declares 262144000", "64 MiB"],
        ),
        ("joint_states.mcap", &[]),
    ];
    harness::replay(&corpus("bag"), expect, harness::bag);
}

/// Every parameter-file reproducer gives the error naming its cause; the
/// valid files read.
#[test]
fn params_reproducers_name_their_cause() {
    let expect: &[(&str, &[&str])] = &[
        ("alias_bomb.yaml", &["fuzz.yaml", "a YAML alias"]),
        ("implausible.yaml", &["fuzz.yaml", "lever_x"]),
        ("odocal.json", &[]),
        ("odocal.yaml", &[]),
        ("two_documents.yaml", &["fuzz.yaml", "2 YAML documents (`---`)", "--params-node"]),
    ];
    harness::replay(&corpus("params"), expect, harness::params);
}
