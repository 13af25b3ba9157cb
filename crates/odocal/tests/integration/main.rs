//! Integration tests of the `odocal` library through its public API, one
//! module per area.
//!
//! One test binary rather than one per file: each integration-test binary
//! links the whole library. Run one area with a filter, e.g.
//! `cargo test -p odocal --test integration golden::`. The Parquet reader's
//! tests (`tests/import_parquet.rs`, feature `parquet`) stay a binary of
//! their own.

mod common;

mod bad_input;
mod bad_input_import;
mod bag_import;
mod bag_psu;
mod golden;
mod import_regression;
mod library_api;
mod real_slices;
mod testtrack_crossrun;
mod testtrack_import;
