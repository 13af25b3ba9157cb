//! The 3-step method's compensation (step 2) on the first segments of a
//! simulated drive, on one thread: a short, repeatable workload to profile
//! the compensation QP (`valgrind --tool=callgrind`) and to check that a
//! change of the solver leaves its results identical to the bit.
//!
//! ```sh
//! cargo run --release --manifest-path crates/odocal-lab/Cargo.toml --target-dir target --bin qp_profile -- \
//!     [--km 24] [--segments 40] [--seed 1]
//! ```
//!
//! Every segment is compensated at two θ: batch Gauss-Newton's estimate on
//! the drive and the paper's θ_0. Prints the QP solves, solver iterations
//! and a fingerprint of every compensated input's bits (FNV-1a), which a
//! bit-identical change of the solver keeps.

use odocal::compensate::{compensate_segments, CompensateOptions, QpOptions};
use odocal::segment::{calibration_segments, SegmentOptions};
use odocal::Theta;
use odocal_lab::{batch_gn_all, simulate_preset, Args, Res};

const USAGE: &str = "qp_profile [--km 24] [--segments 40] [--seed 1]";

fn main() {
    odocal_lab::main_with(run)
}

/// FNV-1a over the bits of `values`, continuing from `hash`.
fn fnv1a(mut hash: u64, values: &[f64]) -> u64 {
    for v in values {
        for byte in v.to_bits().to_le_bytes() {
            hash ^= u64::from(byte);
            hash = hash.wrapping_mul(0x0100_0000_01b3);
        }
    }
    hash
}

fn run() -> Res<()> {
    let mut args = Args::parse(USAGE, &[])?;
    let km: f64 = args.get("km", 24.0)?;
    let count: usize = args.get("segments", 40)?;
    let seed: u64 = args.get("seed", 1)?;
    args.finish()?;
    rayon::ThreadPoolBuilder::new().num_threads(1).build_global()?;
    let drive = simulate_preset("paper", km, seed)?.drive;
    let selection = calibration_segments(&drive, &SegmentOptions::default())?;
    let segments: Vec<_> = selection.iter().take(count).cloned().collect();
    let thetas = [batch_gn_all(&drive)?, Theta::PAPER_INITIAL];
    let out =
        compensate_segments(&drive, &segments, &thetas, &CompensateOptions::default(), &QpOptions::default(), None)?;
    let mut hash = 0xcbf2_9ce4_8422_2325;
    for (a, b) in out.n_rl.iter().zip(&out.n_rr) {
        hash = fnv1a(fnv1a(hash, a), b);
    }
    let s = &out.step;
    println!(
        "{} segments × {} θ: {} QP solves, {:.4} iterations per solve, {} failed, {} fallbacks; fingerprint {hash:016x}",
        segments.len(),
        thetas.len(),
        s.qp_solves,
        s.mean_qp_iterations,
        s.failed_jobs,
        s.fallback_solves
    );
    Ok(())
}
