//! Cross-run check on the six test-track runs of 2024-08-05:
//! calibrate on each run (or on a pair of runs), validate on the others.
//!
//! The lab program `testtrack_crossrun` prints the tables
//! (`cargo run --release --manifest-path crates/odocal-lab/Cargo.toml --bin
//! testtrack_crossrun`; docs/validation.md, "Test track: cross-run", quotes
//! them and the diagnosis): the track is banked (≈ 5.4° in the curves), and
//! with the manifests' `[lateral_acceleration.bank]` (a_y the lateral
//! specific force a_y·cos φ − g·sin φ, φ from the rear antennas) the 3-step
//! on each single run meets the cross-run criterion: never worse than θ_0
//! on another run, mean cross-run Ē_p 2.30 m within 1.5 × the mean own fit
//! 1.56 m (ratio 1.47), none rejected. Without the bank it does not (ratio
//! 1.89, 3 of 30 pairs worse than θ_0): the counter-clockwise and clockwise
//! runs want c_d 0.8 mm apart. With d held at 0 the bank cannot act (the
//! term is d·g·sin φ) and the single-run criterion still fails (ratio
//! 1.71–1.81). These tests assert:
//! - the default method (eiv) and the 3-step on each run:
//!   the full criterion (every run calibrates, never worse than θ_0 on
//!   another run, ratio ≤ 1.5, at most two rejected and not all), and each
//!   θ beats θ_0 on its own run; eiv's mean cross-run Ē_p is no worse than
//!   batch G-N's on all segments; the default's σ for the next drive
//!   contains the other runs' mean in ≥ 80 % of run × parameter cases on
//!   the three design runs and on the three confirming ones, with median
//!   half-widths within 2.5 × the between-run sd;
//! - batch G-N with d held on each run: every run calibrates, none
//!   rejected, each θ beats θ_0 on its own run and on the mean of the
//!   other five;
//! - each counter-clockwise × clockwise pair, batch G-N on every segment
//!   with d held: the full criterion, none rejected;
//! - the same pairs with the 3-step: ratio ≤ 1.5, none failed, at most two
//!   rejected.
//!
//! The default method's check runs in every `cargo test` (about 4 s of CPU
//! in the test profile, which is optimised); the others take 5–10 s each
//! and are in the slow tier, `#[ignore]`d: `cargo test --workspace --
//! --ignored` runs them with the rest of that tier, `cargo test -p odocal
//! --test integration testtrack_crossrun:: -- --ignored` alone.
//! The data live in `data/` at the repository root.

use odocal::{Calibration, CalibrationOptions, Drive, Method, MultiValidation, Param, ValidationDrive};
use odocal::{Verdict, VerdictLevel};

/// Three counter-clockwise runs, then three clockwise ones.
const RUNS: [&str; 6] = ["14-45-26", "15-28-33", "16-06-28", "16-47-33", "17-45-46", "18-01-26"];

/// The criterion's ratio: the mean over runs of the cross-run Ē_p should
/// stay within this multiple of the mean of the runs' own fits.
const CROSS_RUN_OWN_FIT_RATIO: f64 = 1.5;

/// A group's calibration and its validation on the other runs.
#[derive(Debug)]
struct Fit {
    verdict: Verdict,
    /// Ē_p of θ and of θ_0 on the group's own validation segments, m.
    own_m: f64,
    initial_own_m: f64,
    /// θ and θ_0 on every other run.
    others: MultiValidation,
    /// θ, `[c_e, c_d, t_r, d]`, and its σ for the next drive (JSON `sigma`).
    theta: [f64; 4],
    sigma: [Option<f64>; 4],
}

#[derive(Debug)]
struct Row {
    name: String,
    fit: Result<Fit, String>,
}

#[derive(Debug)]
struct CrossRunTable {
    rows: Vec<Row>,
}

#[derive(Debug)]
struct Criteria {
    /// (calibrated on, validated on) wherever θ is worse than θ_0 there.
    worse_than_initial: Vec<(String, String)>,
    mean_cross_m: f64,
    mean_initial_cross_m: f64,
    /// `mean_cross_m` over the mean own-fit Ē_p.
    ratio: f64,
    rejected: usize,
    failed: usize,
}

impl Criteria {
    /// Every group calibrated, never worse than θ_0 on another run, the
    /// ratio within [`CROSS_RUN_OWN_FIT_RATIO`].
    fn pass(&self) -> bool {
        self.failed == 0 && self.worse_than_initial.is_empty() && self.ratio <= CROSS_RUN_OWN_FIT_RATIO
    }
}

impl std::fmt::Display for CrossRunTable {
    /// One line per group: θ's verdict, own Ē_p (θ, θ_0), mean Ē_p on the
    /// other runs (θ, θ_0), m.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for row in &self.rows {
            match &row.fit {
                Ok(r) => writeln!(
                    f,
                    "{}: {} own {:.2} (θ_0 {:.2}) others {:.2} (θ_0 {:.2})",
                    row.name,
                    r.verdict.level,
                    r.own_m,
                    r.initial_own_m,
                    r.others.mean_over_drives_m,
                    r.others.initial_mean_over_drives_m
                )?,
                Err(e) => writeln!(f, "{}: failed: {e}", row.name)?,
            }
        }
        Ok(())
    }
}

impl CrossRunTable {
    fn criteria(&self) -> Criteria {
        let fits: Vec<(&str, &Fit)> =
            self.rows.iter().filter_map(|r| r.fit.as_ref().ok().map(|f| (r.name.as_str(), f))).collect();
        let n = fits.len().max(1) as f64;
        let worse_than_initial = fits
            .iter()
            .flat_map(|(name, f)| {
                f.others
                    .drives
                    .iter()
                    .filter(|d| {
                        d.mean_position_error_m.is_nan() || d.mean_position_error_m > d.initial_mean_position_error_m
                    })
                    .map(|d| (name.to_string(), d.name.clone()))
            })
            .collect();
        let mean_cross_m = fits.iter().map(|(_, f)| f.others.mean_over_drives_m).sum::<f64>() / n;
        let mean_own_m = fits.iter().map(|(_, f)| f.own_m).sum::<f64>() / n;
        Criteria {
            worse_than_initial,
            mean_cross_m,
            mean_initial_cross_m: fits.iter().map(|(_, f)| f.others.initial_mean_over_drives_m).sum::<f64>() / n,
            ratio: mean_cross_m / mean_own_m,
            rejected: fits.iter().filter(|(_, f)| f.verdict.level == VerdictLevel::Rejected).count(),
            failed: self.rows.len() - fits.len(),
        }
    }
}

/// Calibrates each group of runs (a pair is concatenated) and validates
/// its θ and θ_0 on every run outside the group.
fn table(opts: &CalibrationOptions, pairs: bool) -> CrossRunTable {
    let dir = format!("{}/../../examples/psu-mapping-van-testtrack", env!("CARGO_MANIFEST_DIR"));
    let drives: Vec<Drive> = RUNS
        .iter()
        .map(|r| {
            let path = format!("{dir}/run-{r}.toml");
            odocal::load_drive(std::path::Path::new(&path)).unwrap_or_else(|e| panic!("{r}: {e}")).0
        })
        .collect();
    let groups: Vec<Vec<usize>> = if pairs {
        (0..3).flat_map(|i| (3..6).map(move |j| vec![i, j])).collect()
    } else {
        (0..6).map(|i| vec![i]).collect()
    };
    let rows = groups
        .iter()
        .map(|g| {
            let name = g.iter().map(|&i| RUNS[i]).collect::<Vec<_>>().join("+");
            let members: Vec<&Drive> = g.iter().map(|&i| &drives[i]).collect();
            let joint = (members.len() > 1).then(|| Drive::concat(&members).expect("concat"));
            let drive = joint.as_ref().unwrap_or(members[0]);
            let fit = Calibration::new(drive, opts).run().map_err(|e| e.to_string()).map(|r| {
                let others: Vec<ValidationDrive> = (0..RUNS.len())
                    .filter(|j| !g.contains(j))
                    .map(|j| ValidationDrive { name: RUNS[j], drive: &drives[j], reference: None })
                    .collect();
                Fit {
                    verdict: r.verdict.clone(),
                    own_m: r.validation.mean_position_error_m,
                    initial_own_m: r.initial.mean_position_error_m,
                    others: r.validate_on_drives(&others, false).expect("validation on the other runs"),
                    theta: <[_; 4]>::from(r.theta),
                    sigma: <[_; 4]>::from(r.result_sigma()),
                }
            });
            Row { name, fit }
        })
        .collect();
    let t = CrossRunTable { rows };
    eprintln!("{t}{:?}", t.criteria());
    t
}

/// Batch G-N on every cut segment (no yaw-rate selection).
fn batch_gn_all_segments() -> CalibrationOptions {
    let mut opts = CalibrationOptions { method: "batch-gn".parse::<Method>().expect("method"), ..Default::default() };
    opts.segments.min_peak_yaw_rate_rad_per_s = 0.0;
    opts
}

fn batch_gn_all_segments_d_held() -> CalibrationOptions {
    let mut opts = batch_gn_all_segments();
    opts.identify.free = opts.identify.free.into_iter().filter(|p| *p != Param::D).collect();
    opts
}

/// Every row calibrated, at most two rejected (not all), and each θ better
/// than θ_0 on its own run and on the mean of the others.
fn assert_each_theta_improves(t: &CrossRunTable) {
    let c = t.criteria();
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
    assert!(c.mean_cross_m < c.mean_initial_cross_m, "{c:?}");
}

/// The σ for the next drive on single runs (docs/validation.md, "The next
/// drive: six test-track runs"): in the design runs (the first three) and
/// in the confirming runs (the last three) alike, a run's 95 % interval
/// θ̂ ± 1.96 σ contains the mean of the other five runs' estimates in at
/// least 80 % of run × parameter cases (10 of 12), and per parameter the
/// median half-width stays within 2.5 × the six runs' sample sd (an
/// interval merely wide does not count). Measured with the default:
/// 11/12 and 10/12, half-widths 1.33–2.18 × (c_e on the design runs 2.16 ×;
/// 3.06 × with the within-drive noise counted twice).
fn assert_next_drive_sigma_covers_the_other_runs(t: &CrossRunTable) {
    let fits: Vec<&Fit> = t.rows.iter().map(|r| r.fit.as_ref().expect("fit")).collect();
    assert_eq!(fits.len(), 6);
    let sd: [f64; 4] = std::array::from_fn(|p| {
        let m = fits.iter().map(|f| f.theta[p]).sum::<f64>() / 6.0;
        (fits.iter().map(|f| (f.theta[p] - m).powi(2)).sum::<f64>() / 5.0).sqrt()
    });
    for (half, runs) in [("design", 0..3), ("confirm", 3..6)] {
        let mut covered = 0;
        for (p, sd) in sd.iter().enumerate() {
            let mut widths = Vec::new();
            for i in runs.clone() {
                let pooled = (0..6).filter(|&j| j != i).map(|j| fits[j].theta[p]).sum::<f64>() / 5.0;
                let s = fits[i].sigma[p].unwrap_or_else(|| panic!("{}: a σ for parameter {p}", RUNS[i]));
                covered += usize::from((fits[i].theta[p] - pooled).abs() <= 1.96 * s);
                widths.push(1.96 * s);
            }
            widths.sort_by(f64::total_cmp);
            let ratio = widths[1] / sd;
            assert!(ratio <= 2.5, "{half} runs, parameter {p}: median half-width {ratio:.2} × the between-run sd");
        }
        assert!(covered >= 10, "{half} runs: {covered} of 12 run × parameter cases covered");
    }
}

fn three_step() -> CalibrationOptions {
    CalibrationOptions { method: "three-step".parse::<Method>().expect("method"), ..Default::default() }
}

/// The default method (eiv) meets the criterion, its σ for the next drive
/// covers the other runs ([`assert_next_drive_sigma_covers_the_other_runs`]),
/// and it is no worse than batch G-N on all segments across runs (measured: mean Ē_p on the other runs
/// 1.59 m against 2.31 m; ratio 1.40). In the default tier: twelve
/// calibrations and 60 validations take about 4 s of CPU in the test profile.
#[test]
fn default_method_meets_the_cross_run_criterion_and_beats_batch_gn() {
    let t = table(&CalibrationOptions::default(), false);
    let c = t.criteria();
    assert!(c.pass(), "{c:?}\n{t}");
    assert_each_theta_improves(&t);
    assert_next_drive_sigma_covers_the_other_runs(&t);
    let g = table(&batch_gn_all_segments(), false).criteria();
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
#[ignore = "slow tier, six calibrations (~10 s of CPU): cargo test --workspace -- --ignored"]
fn three_step_meets_the_cross_run_criterion_on_single_runs() {
    let t = table(&three_step(), false);
    let c = t.criteria();
    assert!(c.pass(), "{c:?}\n{t}");
    assert_each_theta_improves(&t);
}

#[test]
#[ignore = "slow tier, six calibrations: cargo test --workspace -- --ignored"]
fn batch_gn_with_d_held_improves_on_theta0_across_runs() {
    let t = table(&batch_gn_all_segments_d_held(), false);
    assert_each_theta_improves(&t);
    for row in &t.rows {
        let f = row.fit.as_ref().expect("fit");
        assert_ne!(f.verdict.level, VerdictLevel::Rejected, "{}: {:?}", row.name, f.verdict);
    }
}

#[test]
#[ignore = "slow tier, nine calibrations: cargo test --workspace -- --ignored"]
fn pairs_of_opposite_directions_meet_the_cross_run_criterion() {
    let t = table(&batch_gn_all_segments_d_held(), true);
    let c = t.criteria();
    assert!(c.pass(), "{c:?}\n{t}");
    assert_eq!(c.rejected, 0, "{t}");
    assert_each_theta_improves(&t);
}

#[test]
#[ignore = "slow tier, nine calibrations: cargo test --workspace -- --ignored"]
fn three_step_on_pairs_keeps_the_cross_run_ratio() {
    let t = table(&three_step(), true);
    let c = t.criteria();
    assert!(c.ratio <= CROSS_RUN_OWN_FIT_RATIO, "{c:?}");
    assert_each_theta_improves(&t);
}
