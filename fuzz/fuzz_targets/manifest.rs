//! Fuzz target: `cargo +nightly fuzz run manifest fuzz/corpus/manifest`.
#![no_main]

#[path = "../../crates/odocal/tests/integration/common/harness.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = harness::manifest(data);
});
