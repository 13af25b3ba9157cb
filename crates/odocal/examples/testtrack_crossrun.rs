//! Cross-run check on the PSU van's six test-track runs of 2024-08-05:
//! calibrate on each run, validate on the other five (README quotes its table).
//!
//! ```text
//! cargo run --release -p odocal --example testtrack_crossrun -- \
//!     [--method eiv|three-step|batch-gn] [--min-yaw-rate R] [--segment-length K] [--fix d] [--auto-fix] \
//!     [--keep-one-way] [--pairs] [--json out.json] [--check]
//! ```
//!
//! `--keep-one-way` keeps the paper's turning-only segment selection on
//! these one-direction runs (`CalibrationOptions::keep_one_way_selection`;
//! by default every segment is used there). `--pairs` calibrates each
//! counter-clockwise run jointly with each clockwise one (nine pairs) and
//! validates on the other four runs instead.
//!
//! The manifests are in `examples/psu-mapping-van-testtrack/`, the data in
//! `data/psu-mapping-van-testtrack-2024-08-05/`. For each run it prints the
//! calibrated θ, its verdict, its own Ē_p (validated on the run it was
//! fitted on), its mean Ē_p on the other five runs and θ_0's mean Ē_p on the
//! same five; then the cross-run criteria (never worse than θ_0 on another
//! run, mean cross-run Ē_p within 1.5 × the mean of the runs' own fits, at
//! most two runs rejected).
//! With `--check` it exits with an error unless every run calibrates and
//! those criteria hold (and not every run is rejected): CI runs
//! `--check` with the default settings (`.ci/run`).

use std::error::Error;
use std::path::PathBuf;

use odocal::calibrate::crossrun::{cross_run_groups, CROSS_RUN_OWN_FIT_RATIO};
use odocal::{CalibrationOptions, Method, ParamSet};

/// The six runs of 2024-08-05 (manifest `run-NAME.toml`).
const RUNS: [&str; 6] = ["14-45-26", "15-28-33", "16-06-28", "16-47-33", "17-45-46", "18-01-26"];

fn main() -> Result<(), Box<dyn Error>> {
    let mut opts = CalibrationOptions::default();
    let mut json: Option<PathBuf> = None;
    let mut pairs = false;
    let mut check = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--method" => opts.method = Method::from_name(&value()?)?,
            "--min-yaw-rate" => opts.segments.min_peak_yaw_rate_rad_per_s = value()?.parse()?,
            "--segment-length" => opts.segments.length_steps = value()?.parse()?,
            "--fix" => {
                for p in value()?.parse::<ParamSet>()?.iter() {
                    opts.identify.free.remove(p);
                }
            }
            "--auto-fix" => opts.auto_fix = true,
            "--keep-one-way" => opts.keep_one_way_selection = true,
            "--pairs" => pairs = true,
            "--check" => check = true,
            "--json" => json = Some(PathBuf::from(value()?)),
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../examples/psu-mapping-van-testtrack");
    let mut drives = Vec::new();
    for run in RUNS {
        let (drive, _) = odocal::load_drive(&dir.join(format!("run-{run}.toml")))?;
        drives.push((run, drive));
    }
    let named: Vec<(&str, &odocal::Drive)> = drives.iter().map(|(n, d)| (*n, d)).collect();
    // RUNS: three counter-clockwise runs, then three clockwise ones
    let groups: Vec<Vec<usize>> = if pairs {
        (0..3).flat_map(|i| (3..6).map(move |j| vec![i, j])).collect()
    } else {
        (0..6).map(|i| vec![i]).collect()
    };
    let table = cross_run_groups(&named, &groups, &opts, None)?;
    println!("{table}");
    let c = table.criteria(CROSS_RUN_OWN_FIT_RATIO);
    println!("{c}");
    if let Some(p) = json {
        std::fs::write(&p, serde_json::to_string_pretty(&table)? + "\n")?;
    }
    if check {
        // never worse than θ_0 on another run, the ratio within
        // 1.5, every run calibrated, at most two rejected (and not all)
        if !c.pass() || c.rejected > 2 || c.rejected >= c.runs {
            return Err(format!("the cross-run criterion does not hold:\n{c}").into());
        }
        println!("check passed: the cross-run criterion holds");
    }
    Ok(())
}
