//! A manifest imported as a stream ([`odocal::online::ManifestStream`]),
//! kept on disk ([`odocal::DriveStream::spool`]) and replayed through the
//! online calibrator in memory that does not grow with the drive: the peak
//! heap, counted by this test binary's allocator, of a drive 8 times as
//! long is within 10 % of the short one's (and the whole import's grows
//! with it, so the count can tell).

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use odocal::online::{Calibrator, ManifestStream, OnlineOptions, StreamOptions};
use odocal::{DriveStream, Manifest, Theta};

/// The system allocator, counting the bytes held and their peak.
struct Counting;

static HELD: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// Counting needs the allocator interface, which is `unsafe` by contract;
// every call is passed on to `System` unchanged.
#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = HELD.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        HELD.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            HELD.fetch_sub(layout.size(), Ordering::Relaxed);
            let now = HELD.fetch_add(new_size, Ordering::Relaxed) + new_size;
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Writes a drive of `n` samples at 40 Hz: 10 m/s on a slow weave, two
/// parts (a gap of 2 s in the middle).
fn write_drive(path: &Path, n: usize) {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).expect("create"));
    writeln!(w, "t,px,py,psi,n_rl,n_rr,beta,a_y,part").expect("write");
    let (mut x, mut y) = (0.0f64, 0.0f64);
    for k in 0..n {
        let part = usize::from(k >= n / 2);
        let t = k as f64 * 0.025 + 2.0 * part as f64;
        let psi = 0.3 * (k as f64 * 0.002).sin();
        let w_rad = 0.3 * 0.002 * (k as f64 * 0.002).cos() / 0.025;
        let (n_rl, n_rr) = ((10.0 - 0.8 * w_rad) / 2.0, (10.0 + 0.8 * w_rad) / 2.0);
        writeln!(w, "{t},{x},{y},{psi},{n_rl},{n_rr},0,{},{part}", 10.0 * w_rad).expect("write");
        x += 0.25 * psi.cos();
        y += 0.25 * psi.sin();
    }
    w.flush().expect("flush");
}

/// The peak heap above what was held before `f` ran, bytes.
fn peak_of(f: impl FnOnce()) -> usize {
    let base = HELD.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    f();
    PEAK.load(Ordering::Relaxed) - base
}

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
    assert_eq!(stream.fingerprint().expect("fingerprint").len(), 64);
    let mut cal = Calibrator::new(Theta::PAPER_NOMINAL, None, stream.sample_time_s(), OnlineOptions::default())
        .expect("calibrator");
    let mut pushed = 0;
    cal.push_stream(&stream, 400, |n| pushed = n).expect("push");
    assert_eq!(pushed, stream.len());
    assert!(cal.drive_summary().folded_segments > 0);
    pushed
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
