//! The `odocal` command-line tool.
fn main() {}
