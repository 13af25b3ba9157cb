//! A drive CSV read as a stream and replayed through the online
//! calibrator ([`odocal::io::Replay`]) in memory that does not grow with the
//! drive: the peak heap, counted by this test binary's allocator, of a
//! drive 8 times as long is within 10 % of the short one's (and the whole
//! reader's grows with it, so the count can tell).

#[path = "support/memory.rs"]
mod memory;

use memory::{follow_file, peak_of, write_drive};
use odocal::Drive;

// One test in this binary: the counts are the process's.
#[test]
fn streamed_replay_memory_is_flat_in_the_drive_length() {
    let dir = tempfile::tempdir().expect("tmp");
    let (short, long) = (dir.path().join("short.csv"), dir.path().join("long.csv"));
    write_drive(&short, 12_000);
    write_drive(&long, 96_000);
    let p_short = peak_of(|| assert_eq!(follow_file(&short), 12_000));
    let p_long = peak_of(|| assert_eq!(follow_file(&long), 96_000));
    assert!(
        (p_long as f64) < 1.1 * p_short as f64,
        "peak heap {p_long} B for 96,000 samples against {p_short} B for 12,000"
    );
    // The whole reader holds the drive: its peak grows with it.
    let w_short = peak_of(|| assert_eq!(Drive::read_csv(&short).expect("whole").0.len(), 12_000));
    let w_long = peak_of(|| assert_eq!(Drive::read_csv(&long).expect("whole").0.len(), 96_000));
    eprintln!("peak heap, B: streamed {p_short} and {p_long}, whole {w_short} and {w_long}");
    assert!(w_long > 4 * w_short, "whole reads: {w_long} B against {w_short} B");
    assert!(p_long < w_long / 4, "streamed {p_long} B, whole {w_long} B");
}
