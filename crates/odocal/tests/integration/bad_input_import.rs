//! The import half of the bad-input replay: every manifest reproducer of the
//! bad-input issue (unit mistakes, absurd rates and windows, wrong signal
//! kinds and conventions) ends in one clear error, and mutated valid bundles
//! never panic. Memory stays bounded: the CLI test `bad_input_memory` runs
//! the same bundles under an address-space limit.

use crate::common;

use std::path::{Path, PathBuf};

use common::harness;
use proptest::prelude::*;

fn corpus() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus/import");
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(&dir).expect("corpus folder").map(|e| e.expect("entry").path()).collect();
    files.sort();
    files
}

#[test]
fn import_reproducers_name_their_cause() {
    let expect: &[(&str, &[&str])] = &[
        ("counter_bits_8.bundle", &["wheels.counter_bits"]),
        ("dejitter_window_1e9.bundle", &["streams.wheels.dejitter_window_s", "above the limit"]),
        ("latlon_metres.bundle", &["pose.position.lat", "outside ±90°"]),
        ("max_clock_offset_1e5.bundle", &["output.max_clock_offset_s", "above the limit"]),
        ("nominal_rate_1e7.bundle", &["streams.wheels.nominal_rate_hz", "above the limit"]),
        ("not_a_bundle.bundle", &["no m.toml section"]),
        ("rate_1e6.bundle", &["output.rate_hz", "above the limit"]),
        ("rate_1e9.bundle", &["output.rate_hz", "above the limit"]),
        ("rate_i64max.bundle", &["output.rate_hz", "above the limit"]),
        ("rev_per_s_on_ticks.bundle", &["wheels.rear_left", "ticks"]),
        ("valid.bundle", &[]),
        ("wheel_time_us.bundle", &["spans 3990000 s", "budget"]),
        ("wheel_time_x1000.bundle", &["min_part_s"]),
        ("wheels_negated.bundle", &["wheels.rear_left.sign", "backwards"]),
    ];
    harness::replay(&corpus(), expect, harness::import_bundle);
}

/// Same mutations as the CSV test, with tokens for manifests too; the
/// `=== NAME` section markers are left intact so the bundle stays a bundle.
fn mutate(base: &str, ops: &[(u8, usize, usize)]) -> Vec<u8> {
    const TOKENS: [&str; 12] = ["nan", "inf", "-", ",", "\n", "1e308", "-1e308", "0", "=", "1e9", "9e15", "1e-300"];
    harness::mutate(base, ops, &TOKENS)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 150, ..ProptestConfig::default() })]

    /// A mutated valid bundle imports to a finite drive or a clean error.
    #[test]
    fn mutated_import_never_panics(ops in prop::collection::vec((any::<u8>(), any::<usize>(), any::<usize>()), 1..5)) {
        let base = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus/import/valid.bundle"))
            .expect("valid bundle");
        let _ = harness::import_bundle(&mutate(&base, &ops));
    }
}
