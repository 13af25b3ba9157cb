//! Fuzz target: `cargo +nightly fuzz run csv_drive fuzz/corpus/csv_drive`.
#![no_main]

#[path = "../../crates/odocal/tests/integration/common/harness.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = harness::csv_drive(data);
});
