//! Fuzz target: `cargo +nightly fuzz run bag corpus/bag`.
#![no_main]

#[path = "../../crates/odocal/tests/integration/common/harness.rs"]
mod harness;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = harness::bag(data);
});
