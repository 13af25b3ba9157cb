//! End-to-end tests of the `odocal` binary, one module per area.
//!
//! One test binary rather than one per file: each integration-test binary
//! links the whole library, and eleven of them took ~45 s of the CI's CPU
//! to build. Run one area with a filter, e.g.
//! `cargo test -p odocal-cli --test end_to_end golden::`.

mod common;

mod bad_input;
mod bag;
mod careless;
mod cli;
mod commands;
mod data_safety;
mod docs_quotes;
mod eiv;
mod experiment;
mod extrinsics;
mod follow;
mod golden;
mod heading_offset;
mod help;
mod hostile;
mod html_report;
mod keep_one_way;
mod manifest_settings;
mod misleading;
mod params_out;
mod rough_use;
mod silent_wrong;
mod validate_on_reference;
mod validate_verdict;
