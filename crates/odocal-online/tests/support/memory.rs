//! Shared by the memory tests (each its own test binary, so each counts
//! only its own allocations): a counting global allocator, the peak heap
//! of a closure, a synthetic drive CSV of any length, and the replay of a
//! streamed drive through the online calibrator.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};

use odocal::io::Replay;
use odocal::Theta;
use odocal_online::{Calibrator, OnlineOptions};

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
pub fn write_drive(path: &Path, n: usize) {
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
pub fn peak_of(f: impl FnOnce()) -> usize {
    let base = HELD.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    f();
    PEAK.load(Ordering::Relaxed) - base
}

/// Replays the drive file at `path` (a drive CSV or a manifest) through
/// the online calibrator ([`Replay`], what `odocal follow` pushes); the
/// number of samples pushed. A manifest must be imported as a stream (not
/// whole).
pub fn follow_file(path: &Path) -> usize {
    let drive = Replay::open(path, |line| {
        assert!(!line.contains("imported whole"), "{line}");
        Ok::<(), odocal::Error>(())
    })
    .expect("open");
    assert_eq!(drive.fingerprint().expect("fingerprint").len(), 64);
    let mut cal = Calibrator::new(Theta::PAPER_NOMINAL, None, drive.sample_time_s(), OnlineOptions::default())
        .expect("calibrator");
    cal.push_replay(&drive, |_| {}).expect("push");
    let summary = cal.status().drive;
    assert!(summary.folded_segments > 0);
    summary.samples
}
