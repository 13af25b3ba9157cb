//! Cross-run check on the six test-track runs of 2024-08-05 (issue 10):
//! calibrate on each run (or on a pair of runs), validate on the others.
//!
//! Measured (release, `cargo run --release -p odocal --example
//! testtrack_crossrun -- …`; README, "Cross-run check on the test track",
//! quotes the tables and the diagnosis): the strict criterion
//! (never worse than θ_0 on another run, mean cross-run Ē_p within 1.5 ×
//! the mean own fit) is **not** met by a θ fitted on a single run, with any
//! setting. The counter-clockwise runs (14-45-26, 15-28-33, 16-06-28) and
//! the clockwise ones (16-47-33, 17-45-46, 18-01-26) want c_d about 0.9 mm
//! apart (joint fit of each direction's three runs, d held: +1.24 and
//! +2.12 mm), whatever d, a sideslip β = k·a_y (k = −20 … +20 mrad per
//! m/s²), the clock offset (−0.2 … +0.1 s) or a reference-heading lag
//! (−0.2 … +0.2 s): a yaw effect outside the model with the sign of the
//! turning direction, which a run that turns one way only cannot tell from
//! c_d. Even each direction's joint θ gives a ratio of 1.67 on the six runs.
//! Calibrated on one counter-clockwise and one clockwise run jointly, the
//! criterion holds. These tests assert:
//! - default 3-step on each run (every segment used, as the selected ones
//!   all turn one way: `Warning::OneWayTurns`): every run calibrates, at
//!   most two are rejected, each θ beats θ_0 on its own run and on the mean
//!   of the other five;
//! - batch G-N with d held on each run: the same;
//! - each counter-clockwise × clockwise pair, batch G-N on every segment
//!   with d held: the full criterion (never worse than θ_0 on any of the
//!   other four runs, ratio ≤ 1.5, none rejected);
//! - the same pairs with the default 3-step: ratio ≤ 1.5, none failed, at
//!   most two rejected.
//!
//! Slow in a debug build (six or nine calibrations per test): `#[ignore]`d;
//! run with `cargo test --release -p odocal --test testtrack_crossrun --
//! --ignored`. The data live in ../shared/data beside the repository.

use odocal::crossrun::{cross_run_groups, CrossRunTable, CROSS_RUN_OWN_FIT_RATIO};
use odocal::{CalibrationOptions, Drive, Method, Param, VerdictLevel};

/// Three counter-clockwise runs, then three clockwise ones.
const RUNS: [&str; 6] = ["14-45-26", "15-28-33", "16-06-28", "16-47-33", "17-45-46", "18-01-26"];

fn table(opts: &CalibrationOptions, pairs: bool) -> CrossRunTable {
    let dir = format!("{}/../../examples/psu-mapping-van-testtrack", env!("CARGO_MANIFEST_DIR"));
    let drives: Vec<Drive> = RUNS
        .iter()
        .map(|r| {
            let path = format!("{dir}/run-{r}.toml");
            odocal::load_drive(std::path::Path::new(&path)).unwrap_or_else(|e| panic!("{r}: {e}")).0
        })
        .collect();
    let named: Vec<(&str, &Drive)> = RUNS.iter().copied().zip(drives.iter()).collect();
    let groups: Vec<Vec<usize>> = if pairs {
        (0..3).flat_map(|i| (3..6).map(move |j| vec![i, j])).collect()
    } else {
        (0..6).map(|i| vec![i]).collect()
    };
    let t = cross_run_groups(&named, &groups, opts, None).expect("cross-run");
    eprintln!("{t}\n{}", t.criteria(CROSS_RUN_OWN_FIT_RATIO));
    t
}

fn batch_gn_all_segments_d_held() -> CalibrationOptions {
    let mut opts = CalibrationOptions { method: Method::from_name("batch-gn").expect("method"), ..Default::default() };
    opts.segments.min_peak_yaw_rate_rad_per_s = 0.0;
    opts.identify.free.remove(Param::D);
    opts
}

/// Every row calibrated, at most two rejected (not all), and each θ better
/// than θ_0 on its own run and on the mean of the others.
fn assert_each_theta_improves(t: &CrossRunTable) {
    let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
    assert_eq!(c.failed, 0, "{t}");
    assert!(c.rejected <= 2, "{t}");
    assert!(c.rejected < t.rows.len(), "a build that rejects everything must fail");
    for row in &t.rows {
        let f = row.fit.as_ref().expect("fit");
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

#[test]
#[ignore = "six calibrations: slow in debug; run with --release -- --ignored"]
fn default_three_step_calibrates_every_run_and_improves_on_theta0() {
    assert_each_theta_improves(&table(&CalibrationOptions::default(), false));
}

#[test]
#[ignore = "six calibrations: slow in debug; run with --release -- --ignored"]
fn batch_gn_with_d_held_improves_on_theta0_across_runs() {
    let t = table(&batch_gn_all_segments_d_held(), false);
    assert_each_theta_improves(&t);
    for row in &t.rows {
        let f = row.fit.as_ref().expect("fit");
        assert_ne!(f.verdict.level, VerdictLevel::Rejected, "{}: {:?}", row.name, f.verdict);
    }
}

#[test]
#[ignore = "nine calibrations: slow in debug; run with --release -- --ignored"]
fn pairs_of_opposite_directions_meet_the_cross_run_criterion() {
    let t = table(&batch_gn_all_segments_d_held(), true);
    let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
    assert!(c.pass(), "{c}\n{t}");
    assert_eq!(c.rejected, 0, "{t}");
    assert_each_theta_improves(&t);
}

#[test]
#[ignore = "nine calibrations: slow in debug; run with --release -- --ignored"]
fn default_three_step_on_pairs_keeps_the_cross_run_ratio() {
    let t = table(&CalibrationOptions::default(), true);
    let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
    assert!(c.ratio <= CROSS_RUN_OWN_FIT_RATIO, "{c}");
    assert_each_theta_improves(&t);
}
