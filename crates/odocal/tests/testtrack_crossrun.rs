//! Cross-run check on the six test-track runs of 2024-08-05 (issue 10):
//! calibrate on each run, validate on the other five.
//!
//! Measured (release, `cargo run --release -p odocal --example
//! testtrack_crossrun -- …`; README quotes the tables): neither the default
//! 3-step nor batch G-N meets the strict criteria. The counter-clockwise
//! runs (14-45-26, 15-28-33, 16-06-28) and the clockwise ones (16-47-33,
//! 17-45-46, 18-01-26) want c_d about 1 mm apart, so a θ fitted on one
//! direction is worse than θ_0 on some runs of the other (the reference
//! antenna's lever arm and heading offset, not in θ, are the suspected
//! cause). These tests assert what does hold, and print the rest:
//! - default 3-step: at most two runs end without a usable θ (rejected or
//!   stopped by the guards), not all;
//! - batch G-N on every segment with d held (`--method batch-gn
//!   --min-yaw-rate 0 --fix d`, the best settings found): every run
//!   calibrates, at most two are rejected, each θ beats θ_0 on its own run
//!   and on the mean of the other five.
//!
//! Slow in a debug build (six calibrations and thirty validations per
//! test): `#[ignore]`d; run with `cargo test --release -p odocal --test
//! testtrack_crossrun -- --ignored`. The data live in ../shared/data beside
//! the repository.

use odocal::crossrun::{cross_run, CrossRunTable, CROSS_RUN_OWN_FIT_RATIO};
use odocal::{CalibrationOptions, Drive, Method, Param, VerdictLevel};

const RUNS: [&str; 6] = ["14-45-26", "15-28-33", "16-06-28", "16-47-33", "17-45-46", "18-01-26"];

fn table(opts: &CalibrationOptions) -> CrossRunTable {
    let dir = format!("{}/../../examples/psu-mapping-van-testtrack", env!("CARGO_MANIFEST_DIR"));
    let drives: Vec<Drive> = RUNS
        .iter()
        .map(|r| {
            let path = format!("{dir}/run-{r}.toml");
            odocal::load_drive(std::path::Path::new(&path)).unwrap_or_else(|e| panic!("{r}: {e}")).0
        })
        .collect();
    let named: Vec<(&str, &Drive)> = RUNS.iter().copied().zip(drives.iter()).collect();
    let t = cross_run(&named, opts, None).expect("cross-run");
    eprintln!("{t}\n{}", t.criteria(CROSS_RUN_OWN_FIT_RATIO));
    t
}

#[test]
#[ignore = "six calibrations: slow in debug; run with --release -- --ignored"]
fn default_three_step_leaves_at_most_two_runs_without_a_usable_theta() {
    let t = table(&CalibrationOptions::default());
    let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
    let unusable = c.rejected + c.failed;
    assert!(unusable <= 2, "{unusable} of 6 rejected or stopped\n{t}");
    assert!(unusable < RUNS.len(), "a build that rejects everything must fail");
}

#[test]
#[ignore = "six calibrations: slow in debug; run with --release -- --ignored"]
fn batch_gn_with_d_held_improves_on_theta0_across_runs() {
    let mut opts = CalibrationOptions { method: Method::from_name("batch-gn").expect("method"), ..Default::default() };
    opts.segments.min_peak_yaw_rate_rad_per_s = 0.0;
    opts.identify.free.remove(Param::D);
    let t = table(&opts);
    let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
    assert_eq!(c.failed, 0, "{t}");
    assert!(c.rejected <= 2, "{t}");
    for row in &t.rows {
        let f = row.fit.as_ref().expect("fit");
        assert_ne!(f.verdict.level, VerdictLevel::Rejected, "{}: {:?}", row.name, f.verdict);
        assert!(f.own_m < f.initial_own_m, "{}: own {} vs θ_0 {}", row.name, f.own_m, f.initial_own_m);
        assert!(
            f.others.mean_over_drives_m < f.others.initial_mean_over_drives_m,
            "{}: mean on the others {} vs θ_0 {}",
            row.name,
            f.others.mean_over_drives_m,
            f.others.initial_mean_over_drives_m
        );
    }
    assert!(c.mean_cross_m < c.mean_initial_cross_m, "{c}");
}
