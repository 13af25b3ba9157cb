//! Cross-run check on the six test-track runs of 2024-08-05:
//! calibrate on each run (or on a pair of runs), validate on the others.
//!
//! Measured (release, `cargo run --release -p odocal --example
//! testtrack_crossrun -- …`; README, "Cross-run check on the test track",
//! quotes the tables and the diagnosis): the track is banked (≈ 5.4° in
//! the curves), and with the manifests' `[lateral_acceleration.bank]` (a_y
//! the lateral specific force a_y·cos φ − g·sin φ, φ from the rear
//! antennas) the 3-step on each single run meets the cross-run
//! criterion: never worse than θ_0 on another run, mean cross-run Ē_p
//! 2.30 m within 1.5 × the mean own fit 1.56 m (ratio 1.47), none
//! rejected. Without the bank it does not (ratio 1.89, 3 of 30 pairs worse
//! than θ_0): the counter-clockwise and clockwise runs want c_d 0.8 mm
//! apart. With d held at 0 the bank cannot act (the term is d·g·sin φ) and
//! the single-run criterion still fails (ratio 1.71–1.81). These tests
//! assert:
//! - the default method (eiv) and the 3-step on each run:
//!   the full criterion (every run calibrates, never worse than θ_0 on
//!   another run, ratio ≤ 1.5, at most two rejected and not all), and each
//!   θ beats θ_0 on its own run; eiv's mean cross-run Ē_p is no worse than
//!   batch G-N's on all segments;
//! - batch G-N with d held on each run: every run calibrates, none
//!   rejected, each θ beats θ_0 on its own run and on the mean of the
//!   other five;
//! - each counter-clockwise × clockwise pair, batch G-N on every segment
//!   with d held: the full criterion, none rejected;
//! - the same pairs with the 3-step: ratio ≤ 1.5, none failed, at most two
//!   rejected.
//!
//! The first two run in every `cargo test` (about 10 s of CPU each,
//! measured: the test profile is optimised); the others, about as long each,
//! stay `#[ignore]`d to keep CI's test stage short: run them with `cargo test
//! --release -p odocal --test integration testtrack_crossrun:: -- --ignored`.
//! The data live in `data/` at the repository root.

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

/// Batch G-N on every cut segment (no yaw-rate selection).
fn batch_gn_all_segments() -> CalibrationOptions {
    let mut opts = CalibrationOptions { method: Method::from_name("batch-gn").expect("method"), ..Default::default() };
    opts.segments.min_peak_yaw_rate_rad_per_s = 0.0;
    opts
}

fn batch_gn_all_segments_d_held() -> CalibrationOptions {
    let mut opts = batch_gn_all_segments();
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

fn three_step() -> CalibrationOptions {
    CalibrationOptions { method: Method::from_name("three-step").expect("method"), ..Default::default() }
}

/// The default method (eiv) meets the criterion and is no worse than batch
/// G-N on all segments across runs (measured: mean Ē_p on the other runs 1.59 m against 2.31 m; ratio 1.40). Not
/// ignored: twelve calibrations and 60 validations take about 10 s of CPU in
/// the test profile (opt-level 2), measured.
#[test]
fn default_method_meets_the_cross_run_criterion_and_beats_batch_gn() {
    let t = table(&CalibrationOptions::default(), false);
    let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
    assert!(c.pass(), "{c}\n{t}");
    assert_each_theta_improves(&t);
    let g = table(&batch_gn_all_segments(), false).criteria(CROSS_RUN_OWN_FIT_RATIO);
    assert!(
        c.mean_cross_m <= g.mean_cross_m,
        "eiv {} m vs batch G-N on all segments {} m",
        c.mean_cross_m,
        g.mean_cross_m
    );
}

/// The paper's 3-step meets it too (measured:
/// 2.30 m on the others against 1.56 m own; ratio 1.47).
#[test]
fn three_step_meets_the_cross_run_criterion_on_single_runs() {
    let t = table(&three_step(), false);
    let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
    assert!(c.pass(), "{c}\n{t}");
    assert_each_theta_improves(&t);
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
fn three_step_on_pairs_keeps_the_cross_run_ratio() {
    let t = table(&three_step(), true);
    let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
    assert!(c.ratio <= CROSS_RUN_OWN_FIT_RATIO, "{c}");
    assert_each_theta_improves(&t);
}
