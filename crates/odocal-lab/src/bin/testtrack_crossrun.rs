//! Cross-run check on the PSU van's six test-track runs of 2024-08-05:
//! calibrate on each run, validate on the other five (docs/validation.md,
//! "Test track: cross-run").
//!
//! For each run it prints the calibrated θ, its verdict, its own Ē_p
//! (validated on the run it was fitted on), its mean Ē_p on the other five
//! runs and θ_0's mean Ē_p on the same five; then the cross-run criteria
//! (never worse than θ_0 on another run, mean cross-run Ē_p within 1.5 × the
//! mean of the runs' own fits, at most two runs rejected). `--pairs`
//! calibrates each counter-clockwise run jointly with each clockwise one
//! (nine pairs) and validates on the other four runs. With `--check` it
//! exits with an error unless every run calibrates and those criteria hold
//! (and not every run is rejected).

use std::path::PathBuf;

use odocal::{CalibrationOptions, Method, ParamSet};
use odocal_lab::crossrun::{cross_run_groups, CROSS_RUN_OWN_FIT_RATIO};
use odocal_lab::{testtrack_runs, Args, Res};

const USAGE: &str = "testtrack_crossrun [--method eiv|three-step|batch-gn] [--min-yaw-rate R] [--segment-length K]
    [--fix d] [--auto-fix] [--keep-one-way] [--pairs] [--json out.json] [--check]

--keep-one-way keeps the paper's turning-only segment selection on these
one-direction runs (by default every segment is used there).";

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &["auto-fix", "keep-one-way", "pairs", "check"])?;
    let mut opts =
        CalibrationOptions { method: a.get("method", "eiv".to_string())?.parse::<Method>()?, ..Default::default() };
    opts.segments.min_peak_yaw_rate_rad_per_s = a.get("min-yaw-rate", opts.segments.min_peak_yaw_rate_rad_per_s)?;
    opts.segments.length_steps = a.get("segment-length", opts.segments.length_steps)?;
    for p in a.get("fix", ParamSet::default())? {
        opts.identify.free = opts.identify.free.without(p);
    }
    opts.auto_fix = a.flag("auto-fix");
    opts.keep_one_way_selection = a.flag("keep-one-way");
    let json: Option<PathBuf> = a.opt("json")?;
    let (pairs, check) = (a.flag("pairs"), a.flag("check"));
    a.finish()?;

    let drives = testtrack_runs()?;
    let named: Vec<(&str, &odocal::Drive)> = drives.iter().map(|(n, d)| (*n, d)).collect();
    // Three counter-clockwise runs, then three clockwise ones.
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
        if !c.pass() || c.rejected > 2 || c.rejected >= c.runs {
            return Err(format!("the cross-run criterion does not hold:\n{c}").into());
        }
        println!("check passed: the cross-run criterion holds");
    }
    Ok(())
}
