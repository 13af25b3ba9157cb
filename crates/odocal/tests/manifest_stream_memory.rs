//! A manifest imported as a stream ([`odocal::online::ManifestStream`]),
//! kept on disk ([`odocal::DriveStream::spool`]) and replayed through the
//! online calibrator in memory that does not grow with the drive: the peak
//! heap, counted by this test binary's allocator, of a drive 8 times as
//! long is within 10 % of the short one's (and the whole import's grows
//! with it, so the count can tell).

use std::path::Path;

#[path = "support/memory.rs"]
mod memory;

use memory::{peak_of, replay_stream, write_drive};
use odocal::online::{ManifestStream, StreamOptions};
use odocal::{DriveStream, Manifest};

/// A manifest over the drive CSV `csv`: its columns as the streams'
/// (wheels in rev/s, the pose with its heading, a_y as an IMU's), the
/// clock offset estimated.
fn write_manifest(path: &Path, csv: &str) {
    let text = format!(
        r#"[output]
rate_hz = 40.0
[streams.drive]
file = "{csv}"
time_column = "t"
[wheels]
stream = "drive"
signal = "rev_per_s"
rear_left = {{ column = "n_rl" }}
rear_right = {{ column = "n_rr" }}
[pose]
stream = "drive"
[pose.position]
kind = "local"
x = "px"
y = "py"
[pose.heading]
column = "psi"
convention = "enu"
[lateral_acceleration]
source = "imu"
stream = "drive"
column = "a_y"
"#
    );
    std::fs::write(path, text).expect("write manifest");
}

/// Imports the manifest at `path` as a stream and replays it.
fn replay(path: &Path) -> usize {
    let m = Manifest::from_path(path).expect("manifest");
    let mut s = ManifestStream::open(&m, StreamOptions::default()).expect("stream");
    let stream = DriveStream::spool(path, 0.025, || Ok(s.next_chunk(400)?.map(|c| (c.t, c.signals, c.starts_part))))
        .expect("spool");
    replay_stream(&stream)
}

// One test in this binary: the counts are the process's.
#[test]
fn streamed_manifest_replay_memory_is_flat_in_the_drive_length() {
    let dir = tempfile::tempdir().expect("tmp");
    let (short, long) = (dir.path().join("short.toml"), dir.path().join("long.toml"));
    write_drive(&dir.path().join("short.csv"), 24_000);
    write_drive(&dir.path().join("long.csv"), 192_000);
    write_manifest(&short, "short.csv");
    write_manifest(&long, "long.csv");
    let whole = |p: &Path| odocal::import(&Manifest::from_path(p).expect("manifest")).expect("import").drive.len();
    let (n_short, n_long) = (whole(&short), whole(&long));
    let p_short = peak_of(|| assert_eq!(replay(&short), n_short));
    let p_long = peak_of(|| assert_eq!(replay(&long), n_long));
    let w_short = peak_of(|| assert_eq!(whole(&short), n_short));
    let w_long = peak_of(|| assert_eq!(whole(&long), n_long));
    eprintln!("peak heap, B: streamed {p_short} and {p_long}, whole {w_short} and {w_long}");
    assert!(
        (p_long as f64) < 1.1 * p_short as f64,
        "peak heap {p_long} B for {n_long} samples against {p_short} B for {n_short}"
    );
    assert!(w_long > 4 * w_short, "whole imports: {w_long} B against {w_short} B");
    assert!(p_long < w_long / 4, "streamed {p_long} B, whole {w_long} B");
}
