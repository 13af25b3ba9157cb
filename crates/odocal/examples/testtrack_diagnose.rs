//! Why a θ fitted on one test-track run does worse on runs driven the other
//! way (issue 10): the measurements README's "Cross-run check on the test
//! track" quotes.
//!
//! ```text
//! [HEADING_SHIFT=m] [TRACK_DIR=dir] cargo run --release -p odocal --example testtrack_diagnose -- K1 K2 …
//! ```
//!
//! For each sideslip gain K (mrad per m/s²) the six runs' β is replaced by
//! K·a_y (the manifests set β = 0 and derive a_y from the wheels); then it
//! prints the joint batch-G-N fit (every segment, d held and free) of the
//! three counter-clockwise runs, the three clockwise ones and all six, and
//! the cross-run summary of the default 3-step, batch G-N with d held and
//! batch G-N. `HEADING_SHIFT=m` takes the reference heading m samples
//! (25 ms each) later, to test a heading lag; `TRACK_DIR` reads the
//! manifests from another directory (copies with another clock offset,
//! say). `K = 0` without either is the data as imported.
use std::error::Error;
use std::path::PathBuf;

use odocal::calibrate::crossrun::{cross_run, CROSS_RUN_OWN_FIT_RATIO};
use odocal::{calibrate, CalibrationOptions, Drive, Method, Param};

const RUNS: [&str; 6] = ["14-45-26", "15-28-33", "16-06-28", "16-47-33", "17-45-46", "18-01-26"];

/// `d` with β = k·a_y (and the reference heading shifted by `HEADING_SHIFT` samples).
fn with_beta(d: &Drive, k: f64) -> Result<Drive, Box<dyn Error>> {
    let mut s = d.measured().clone();
    s.beta = d.a_y().iter().map(|a| k * a).collect();
    // HEADING_SHIFT=m: the reference heading taken m samples later (m < 0: earlier)
    let m: i64 = std::env::var("HEADING_SHIFT").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
    if m != 0 {
        let n = s.psi.len() as i64;
        s.psi = (0..n).map(|i| d.psi()[(i + m).clamp(0, n - 1) as usize]).collect();
    }
    let mut b = Drive::builder(d.t().to_vec(), s).sample_time_s(d.sample_time_s()).parts(d.parts().to_vec());
    if let Some(m) = d.reference_measured() {
        b = b.reference_measured(m.to_vec());
    }
    Ok(b.build()?)
}

fn main() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let ks: Vec<f64> = args.iter().map(|a| a.parse::<f64>().map(|k| k * 1e-3)).collect::<Result<_, _>>()?;
    let dir = std::env::var("TRACK_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|_| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/psu-mapping-van-testtrack"));
    let mut base = Vec::new();
    for run in RUNS {
        base.push(odocal::load_drive(&dir.join(format!("run-{run}.toml")))?.0);
    }
    let gn = |fix_d: bool| {
        let mut o = CalibrationOptions { method: Method::from_name("batch-gn").expect("m"), ..Default::default() };
        o.segments.min_peak_yaw_rate_rad_per_s = 0.0;
        if fix_d {
            o.identify.free.remove(Param::D);
        }
        o
    };
    for k in ks {
        let drives: Vec<Drive> = base.iter().map(|d| with_beta(d, k)).collect::<Result<_, _>>()?;
        let refs: Vec<&Drive> = drives.iter().collect();
        println!("=== k = {:+.1} mrad/(m/s²)", k * 1e3);
        for fix_d in [true, false] {
            let o = gn(fix_d);
            for (label, set) in [("CCW", &refs[..3]), ("CW", &refs[3..]), ("all", &refs[..])] {
                let j = Drive::concat(set)?;
                let r = calibrate(&j, &o, None)?;
                println!(
                    "joint {label:3} fix_d={fix_d}: c_e {:.5} c_d {:+.3} mm t_r {:.4} d {:+.3}  Ē_p {:.3} (θ_0 {:.3})",
                    r.theta.c_e,
                    r.theta.c_d * 1e3,
                    r.theta.t_r,
                    r.theta.d * 1e3,
                    r.validation.mean_position_error_m,
                    r.initial.mean_position_error_m
                );
            }
        }
        let named: Vec<(&str, &Drive)> = RUNS.iter().copied().zip(drives.iter()).collect();
        for (label, o) in [("default", CalibrationOptions::default()), ("gn fix d", gn(true)), ("gn", gn(false))] {
            let t = cross_run(&named, &o, None)?;
            let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
            let cd: Vec<String> = t
                .rows
                .iter()
                .map(|r| r.fit.as_ref().map(|f| format!("{:+.2}", f.theta.c_d * 1e3)).unwrap_or("fail".into()))
                .collect();
            println!(
                "crossrun {label:9}: own {:.3} cross {:.3} ratio {:.2} worse {} rejected {} failed {}  c_d [{}]",
                c.mean_own_m,
                c.mean_cross_m,
                c.ratio,
                c.worse_than_initial.len(),
                c.rejected,
                c.failed,
                cd.join(" ")
            );
        }
    }
    Ok(())
}
