//! Why a θ fitted on one test-track run does worse on runs driven the other
//! way: the runs' sideslip and the reference heading's timing, varied.
//!
//! For each sideslip gain K (mrad per m/s²) the six runs' β is replaced by
//! K·a_y (the manifests set β = 0 and derive a_y from the wheels); then it
//! prints the joint batch-G-N fit (every segment, d held and free) of the
//! three counter-clockwise runs, the three clockwise ones and all six, and
//! the cross-run summary of the default method, batch G-N with d held and
//! batch G-N. `--heading-shift m` takes the reference heading m samples
//! (25 ms each) later, to test a heading lag; `--track-dir` reads the
//! manifests from another directory (copies with another clock offset,
//! say). `K = 0` without either is the data as imported.

use std::path::PathBuf;

use odocal::Drive;
use odocal_lab::{print_cross_runs, print_joint_fits, testtrack_runs, with_signals, Args, Res, TESTTRACK_RUNS};

const USAGE: &str = "testtrack_diagnose [--heading-shift M] [--track-dir DIR] K1 K2 …   (K in mrad/(m/s²))";

/// `d` with β = k·a_y and the reference heading taken `shift` samples later
/// (earlier for shift < 0).
fn with_beta(d: &Drive, k: f64, shift: i64) -> Result<Drive, odocal::Error> {
    let mut s = d.measured().clone();
    s.beta = d.measured().a_y.iter().map(|a| k * a).collect();
    if shift != 0 {
        let n = s.psi.len() as i64;
        s.psi = (0..n).map(|i| d.measured().psi[(i + shift).clamp(0, n - 1) as usize]).collect();
    }
    with_signals(d, s)
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &[])?;
    let shift: i64 = a.get("heading-shift", 0)?;
    let dir: Option<PathBuf> = a.opt("track-dir")?;
    let ks: Vec<f64> = a.positional().iter().map(|k| k.parse::<f64>().map(|k| k * 1e-3)).collect::<Result<_, _>>()?;
    a.finish()?;
    let base: Vec<Drive> = match dir {
        None => testtrack_runs()?.into_iter().map(|(_, d)| d).collect(),
        Some(dir) => TESTTRACK_RUNS
            .iter()
            .map(|(run, _)| Ok(odocal::load_drive(dir.join(format!("run-{run}.toml")))?.0))
            .collect::<Res<_>>()?,
    };
    for k in ks {
        let drives: Vec<Drive> = base.iter().map(|d| with_beta(d, k, shift)).collect::<Result<_, _>>()?;
        println!("=== k = {:+.1} mrad/(m/s²), heading shift {shift} samples", k * 1e3);
        print_joint_fits(&drives)?;
        print_cross_runs(&drives, false)?;
    }
    Ok(())
}
