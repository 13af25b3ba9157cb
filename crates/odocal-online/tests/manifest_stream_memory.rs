//! A manifest imported as a stream, kept on disk and replayed through the
//! online calibrator ([`odocal::io::Replay`]) in memory that does not grow with the drive: the peak
//! heap, counted by this test binary's allocator, of a drive 8 times as
//! long is within 10 % of the short one's (and the whole import's grows
//! with it, so the count can tell); with an IMU's a_y, and with a_y from
//! the wheels corrected for the road bank of two antennas.

use std::io::{BufRead, Write};
use std::path::Path;

#[path = "support/memory.rs"]
mod memory;

use memory::{follow_file, peak_of, write_drive};
use odocal::Manifest;

/// Two antennas 1.5 m apart across the vehicle of the drive CSV at
/// `drive`, on a road whose roll goes slowly between ±1.1°: `left.csv`
/// and `right.csv` (time, lat, lon, alt) beside it.
fn write_antennas(drive: &Path) {
    let dir = drive.parent().expect("folder");
    let reader = std::io::BufReader::new(std::fs::File::open(drive).expect("open"));
    let file = |name: &str| std::io::BufWriter::new(std::fs::File::create(dir.join(name)).expect("create"));
    let (mut left, mut right) = (file("left.csv"), file("right.csv"));
    for w in [&mut left, &mut right] {
        writeln!(w, "t,lat,lon,alt").expect("write");
    }
    let (deg_n, deg_e) = (111_000.0, 111_000.0 * 40f64.to_radians().cos());
    for (k, line) in reader.lines().skip(1).enumerate() {
        let line = line.expect("line");
        let v: Vec<f64> = line.split(',').take(4).map(|x| x.parse().expect("number")).collect();
        let (t, x, y, psi) = (v[0], v[1], v[2], v[3]);
        let sin_roll = 0.02 * (k as f64 * 0.001).sin();
        for (w, side) in [(&mut left, 1.0), (&mut right, -1.0)] {
            let (e, n) = (x - side * 0.75 * psi.sin(), y + side * 0.75 * psi.cos());
            let alt = 300.0 - side * 0.75 * sin_roll;
            writeln!(w, "{t},{},{},{alt}", 40.0 + n / deg_n, -77.0 + e / deg_e).expect("write");
        }
    }
}

/// A manifest over the drive CSV `csv`: its columns as the streams'
/// (wheels in rev/s, the pose with its heading, a_y as an IMU's or, with
/// `bank`, from the wheels with the road bank of [`write_antennas`]), the
/// clock offset estimated.
fn write_manifest(path: &Path, csv: &str, bank: bool) {
    let lateral = if bank {
        r#"[lateral_acceleration]
source = "from_wheels"
smoothing_s = 0.5
[lateral_acceleration.bank]
left = "left"
right = "right"
lat = "lat"
lon = "lon"
alt = "alt"
baseline_m = 1.5
[streams.left]
file = "left.csv"
time_column = "t"
[streams.right]
file = "right.csv"
time_column = "t"
"#
    } else {
        r#"[lateral_acceleration]
source = "imu"
stream = "drive"
column = "a_y"
"#
    };
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
{lateral}"#
    );
    std::fs::write(path, text).expect("write manifest");
}

// One test in this binary: the counts are the process's.
#[test]
#[ignore = "slow tier, a memory claim (three manifest replays, ~8 s): cargo test --workspace -- --ignored"]
fn streamed_manifest_replay_memory_is_flat_in_the_drive_length() {
    for bank in [false, true] {
        flat_in_the_drive_length(bank);
    }
}

fn flat_in_the_drive_length(bank: bool) {
    let (a, b) = (tempfile::tempdir().expect("tmp"), tempfile::tempdir().expect("tmp"));
    let (short, long) = (a.path().join("short.toml"), b.path().join("long.toml"));
    for (dir, name, n, manifest) in [(&a, "short.csv", 24_000, &short), (&b, "long.csv", 192_000, &long)] {
        write_drive(&dir.path().join(name), n);
        if bank {
            write_antennas(&dir.path().join(name));
        }
        write_manifest(manifest, name, bank);
    }
    let whole = |p: &Path| odocal::import(&Manifest::from_path(p).expect("manifest")).expect("import").0.len();
    let (n_short, n_long) = (whole(&short), whole(&long));
    let p_short = peak_of(|| assert_eq!(follow_file(&short), n_short));
    let p_long = peak_of(|| assert_eq!(follow_file(&long), n_long));
    let w_short = peak_of(|| assert_eq!(whole(&short), n_short));
    let w_long = peak_of(|| assert_eq!(whole(&long), n_long));
    let what = if bank { "a_y from the wheels and the road bank" } else { "an IMU's a_y" };
    eprintln!("{what}: peak heap, B: streamed {p_short} and {p_long}, whole {w_short} and {w_long}");
    assert!(
        (p_long as f64) < 1.1 * p_short as f64,
        "{what}: peak heap {p_long} B for {n_long} samples against {p_short} B for {n_short}"
    );
    assert!(w_long > 4 * w_short, "whole imports: {w_long} B against {w_short} B");
    assert!(p_long < w_long / 4, "streamed {p_long} B, whole {w_long} B");
}
