//! Raw batch Gauss-Newton against the 3-step compensated method on simulated
//! drives (docs/validation.md, "The 3-step method": `study --km 6 --seeds 5`).
//!
//! For every noise preset and seed (seeds 1..=S) it simulates a drive and runs:
//! - raw batch G-N from θ_0 on `--batches` random batches of N = 5 and N = 10
//!   selected segments, and on all selected segments at once;
//! - the 3-step method (docs/method.md §6: 50 batches of N = 10, 5 picks, every selected
//!   segment compensated), its step 3 on all compensated segments (θ_B,F) and
//!   on `--batches` random batches of N = 5 and N = 10 compensated segments;
//! - step 2 + 3 with the inputs compensated at θ_true only, and at θ_0 only,
//!   to see whether step 3 follows the θ used for compensation;
//! - the reachable minimum Ē_p,min once per drive (reduced swarm: 20
//!   particles, 30 iterations, 100 Nelder-Mead iterations; seeded with θ_true,
//!   θ_0 and every all-segment estimate).
//!
//! Metrics: |θ − θ_true| per parameter and Ē_p − Ē_p,min.

use std::fmt::Write as _;
use std::time::Instant;

use odocal::compensate::SolverKind;
use odocal::compensate::{compensate_segments, CompensateOptions, CompensatedInputs, QpOptions};
use odocal::identify::IdentifyOptions;
use odocal::research::{calibrate_detailed, random_batches, reachable_minimum, score_batches};
use odocal::segment::Segment;
use odocal::segment::SegmentData;
use odocal::{mean_position_error, Drive, ReachableOptions, Theta};
use odocal::{CalibrationOptions, Method, ThreeStepOptions};
use odocal_lab::report_json::three_step_part;
use odocal_lab::{median, simulate_preset, Args, Res};
use serde::Serialize;

const USAGE: &str = "study [--km 6] [--seeds 5] [--noises off,white,paper,high] [--batches 10] [--solver structured]
    [--json study.json]";

/// Mixed into a drive's seed to draw the random batches of the study.
const RANDOM_BATCH_SEED_SALT: u64 = 0xa5;

/// One estimate's errors: |Δθ| per parameter (SI) and Ē_p − Ē_p,min (m).
#[derive(Debug, Clone, Copy, Serialize)]
struct Err4 {
    abs_err: [f64; 4],
    excess_m: f64,
}

#[derive(Debug, Clone, Serialize)]
struct DriveResult {
    noise: String,
    seed: u64,
    selected: usize,
    validation: usize,
    e_true_m: f64,
    e_min_m: f64,
    e_nominal_m: f64,
    /// method name → errors of each run (one for "all", `batches` for random batches)
    methods: Vec<(String, Vec<Err4>)>,
    theta_true: Theta,
    mean_theta_bi: Theta,
    theta_bf: Theta,
    theta_bf_comp_true: Theta,
    theta_bf_comp_theta0: Theta,
    failed_jobs: usize,
    jobs: usize,
    time_s: f64,
}

struct Settings {
    km: f64,
    seeds: u64,
    noises: Vec<String>,
    batches: usize,
    solver: SolverKind,
    json: Option<String>,
}

fn parse_args() -> Res<Settings> {
    let mut a = Args::parse(USAGE, &[])?;
    let s = Settings {
        km: a.get("km", 6.0)?,
        seeds: a.get("seeds", 5)?,
        noises: a.list("noises", &["off", "white", "paper", "high"]),
        batches: a.get("batches", 10)?,
        solver: a.get("solver", SolverKind::Structured)?,
        json: a.opt("json")?,
    };
    a.finish()?;
    Ok(s)
}

fn abs_diff(a: &Theta, b: &Theta) -> [f64; 4] {
    let (a, b) = (<[_; 4]>::from(a), <[_; 4]>::from(b));
    [(a[0] - b[0]).abs(), (a[1] - b[1]).abs(), (a[2] - b[2]).abs(), (a[3] - b[3]).abs()]
}

fn mean_theta(ts: &[Theta]) -> Theta {
    let mut v = nalgebra::Vector4::zeros();
    for t in ts {
        v += nalgebra::Vector4::from(<[_; 4]>::from(t));
    }
    Theta::from(<[f64; 4]>::from(v / ts.len().max(1) as f64))
}

/// G-N from θ_0 on random batches of `n` segments of `data` (all when `n` is None).
#[allow(clippy::too_many_arguments)]
fn runs(
    drive: &Drive,
    data: &[SegmentData<'_>],
    n: Option<usize>,
    count: usize,
    seed: u64,
    val: &[Segment],
    theta0: &Theta,
    id: &IdentifyOptions,
) -> Vec<Theta> {
    let batches = match n {
        Some(n) => random_batches(data.len(), n, count, seed),
        None => vec![(0..data.len()).collect()],
    };
    score_batches(drive, data, &batches, val, theta0, id, None)
        .into_iter()
        .filter_map(|r| r.ok().map(|b| b.score.theta))
        .collect()
}

fn study_drive(noise: &str, seed: u64, a: &Settings) -> Res<DriveResult> {
    let t0 = Instant::now();
    let sim = simulate_preset(noise, a.km, seed)?;
    let drive = &sim.drive;
    let truth = sim.sidecar.theta_true;
    let qp = QpOptions::from(a.solver);
    let method = Method::ThreeStep(ThreeStepOptions { qp: qp.clone(), ..Default::default() });
    let opts = CalibrationOptions { method, seed, ..Default::default() };
    let det = calibrate_detailed(drive, None, &opts, None)?;
    let (val, sel) = (&det.validation, &det.selected);
    let comp = det.compensated.as_ref().ok_or("3-step returned no compensated inputs")?;
    let init = three_step_part(&det.report).ok_or("3-step returned no step 1")?.initial_step;
    let (theta0, id) = (opts.theta0, opts.identify.clone());
    let raw: Vec<SegmentData> = sel.iter().map(|s| SegmentData::new(drive, s)).collect();
    let cdata = comp.segment_data(drive);

    let mut estimates: Vec<(String, Vec<Theta>)> = Vec::new();
    for n in [5usize, 10] {
        estimates.push((
            format!("raw G-N, N = {n}"),
            runs(drive, &raw, Some(n), a.batches, seed ^ RANDOM_BATCH_SEED_SALT, val, &theta0, &id),
        ));
        estimates.push((
            format!("3-step, final N = {n}"),
            runs(drive, &cdata, Some(n), a.batches, seed ^ RANDOM_BATCH_SEED_SALT, val, &theta0, &id),
        ));
    }
    estimates.push(("raw G-N, all selected".into(), runs(drive, &raw, None, 1, 0, val, &theta0, &id)));
    estimates.push(("3-step, final all (θ_B,F)".into(), vec![det.report.theta]));

    // Step 2 + 3 with inputs compensated at one given θ.
    let comp_at = |theta: &Theta| -> Res<(Theta, CompensatedInputs)> {
        let c = compensate_segments(drive, sel, &[*theta], &CompensateOptions::default(), &qp, None)?;
        let d = c.segment_data(drive);
        let t = runs(drive, &d, None, 1, 0, val, &theta0, &id).first().copied().ok_or("final G-N failed")?;
        Ok((t, c))
    };
    let (bf_true, c_true) = comp_at(&truth)?;
    let (bf_theta0, c_theta0) = comp_at(&theta0)?;
    estimates.push(("compensated at θ_true, final all".into(), vec![bf_true]));
    estimates.push(("compensated at θ_0, final all".into(), vec![bf_theta0]));
    estimates.push(("θ_true (reference)".into(), vec![truth]));

    // Reachable minimum, reduced swarm, seeded with the all-segment estimates.
    let mut starts = vec![truth, theta0];
    for (name, ts) in &estimates {
        if !name.contains("N =") {
            starts.extend(ts.iter().copied());
        }
    }
    let ro = ReachableOptions {
        particles: 20,
        iterations: 30,
        refine_iterations: 100,
        seed,
        starts,
        ..ReachableOptions::around(&theta0)
    };
    let rm = reachable_minimum(drive, val, &ro, None)?;
    let e_min = rm.mean_position_error_m;
    let ep = |t: &Theta| mean_position_error(drive, val, t).map(|v| v.mean_position_error_m);
    let mut methods = Vec::new();
    for (name, ts) in &estimates {
        let mut errs = Vec::new();
        for t in ts {
            errs.push(Err4 { abs_err: abs_diff(t, &truth), excess_m: ep(t)? - e_min });
        }
        methods.push((name.clone(), errs));
    }
    let picked: Vec<Theta> = init.picked.iter().map(|p| p.theta).collect();
    Ok(DriveResult {
        noise: noise.to_string(),
        seed,
        selected: sel.len(),
        validation: val.len(),
        e_true_m: ep(&truth)?,
        e_min_m: e_min,
        e_nominal_m: ep(&Theta::PAPER_NOMINAL)?,
        methods,
        theta_true: truth,
        mean_theta_bi: mean_theta(&picked),
        theta_bf: det.report.theta,
        theta_bf_comp_true: bf_true,
        theta_bf_comp_theta0: bf_theta0,
        failed_jobs: comp.step.failed_jobs + c_true.step.failed_jobs + c_theta0.step.failed_jobs,
        jobs: comp.step.jobs + c_true.step.jobs + c_theta0.step.jobs,
        time_s: t0.elapsed().as_secs_f64(),
    })
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Markdown tables for one noise preset.
fn tables(noise: &str, rs: &[&DriveResult]) -> String {
    let mut o = String::new();
    let seeds: Vec<String> = rs.iter().map(|r| r.seed.to_string()).collect();
    let _ = writeln!(
        o,
        "### noise `{noise}` (seeds {}; {:.0} selected / {:.0} validation segments per drive on average)\n",
        seeds.join(", "),
        mean(&rs.iter().map(|r| r.selected as f64).collect::<Vec<_>>()),
        mean(&rs.iter().map(|r| r.validation as f64).collect::<Vec<_>>())
    );
    let col = |f: fn(&DriveResult) -> f64| rs.iter().map(|r| f(r)).collect::<Vec<f64>>();
    let _ = writeln!(
        o,
        "Ē_p,min (reachable minimum) mean {:.3} m (per seed: {}); Ē_p(θ_true) − Ē_p,min mean {:.3} m; Ē_p(θ_nom) − Ē_p,min mean {:.3} m. QP jobs failed: {} of {}.\n",
        mean(&col(|r| r.e_min_m)),
        col(|r| r.e_min_m).iter().map(|e| format!("{e:.3}")).collect::<Vec<_>>().join(", "),
        mean(&col(|r| r.e_true_m - r.e_min_m)),
        mean(&col(|r| r.e_nominal_m - r.e_min_m)),
        rs.iter().map(|r| r.failed_jobs).sum::<usize>(),
        rs.iter().map(|r| r.jobs).sum::<usize>()
    );
    let _ = writeln!(
        o,
        "| method | runs | Ē_p − Ē_p,min (m) | abs Δc_e (mm) | abs Δc_d (mm) | abs Δt_r (mm) | abs Δd (mm/(m/s²)) |\n|---|---|---|---|---|---|---|"
    );
    let names: Vec<String> = rs[0].methods.iter().map(|m| m.0.clone()).collect();
    for name in names {
        let pooled: Vec<Err4> = rs
            .iter()
            .flat_map(|r| r.methods.iter().filter(|m| m.0 == name).flat_map(|m| m.1.iter().copied()))
            .collect();
        let cell = |v: Vec<f64>| format!("{:.3} / {:.3}", mean(&v), median(&v));
        let _ = writeln!(
            o,
            "| {name} | {} | {} | {} | {} | {} | {} |",
            pooled.len(),
            cell(pooled.iter().map(|e| e.excess_m).collect()),
            cell(pooled.iter().map(|e| e.abs_err[0] * 1e3).collect()),
            cell(pooled.iter().map(|e| e.abs_err[1] * 1e3).collect()),
            cell(pooled.iter().map(|e| e.abs_err[2] * 1e3).collect()),
            cell(pooled.iter().map(|e| e.abs_err[3] * 1e3).collect()),
        );
    }
    let _ = writeln!(o, "\nCells are mean / median over all runs of all seeds.\n");

    // Does step 3 follow the θ of compensation?
    let _ = writeln!(
        o,
        "Step 3 vs the θ of compensation (means over seeds; c_e, t_r in m, c_d in mm, d in mm/(m/s²)):\n\n| | c_e | c_d | t_r | d |\n|---|---|---|---|---|"
    );
    let show = |o: &mut String, name: &str, f: &dyn Fn(&DriveResult) -> Theta| {
        let ts: Vec<Theta> = rs.iter().map(|r| f(r)).collect();
        let m = mean_theta(&ts);
        let _ = writeln!(o, "| {name} | {:.5} | {:.3} | {:.4} | {:.3} |", m.c_e, m.c_d * 1e3, m.t_r, m.d * 1e3);
    };
    show(&mut o, "θ_true", &|r| r.theta_true);
    show(&mut o, "θ_0", &|_| Theta::PAPER_INITIAL);
    show(&mut o, "mean of θ_B,I (compensation θs)", &|r| r.mean_theta_bi);
    show(&mut o, "θ_B,F (compensated at the θ_B,I)", &|r| r.theta_bf);
    show(&mut o, "θ_B,F (compensated at θ_true)", &|r| r.theta_bf_comp_true);
    show(&mut o, "θ_B,F (compensated at θ_0)", &|r| r.theta_bf_comp_theta0);
    // Follow ratio: how far θ_B,F moves when the compensation θ moves from θ_true to θ_0.
    let ratio = |i: usize| {
        let v: Vec<f64> = rs
            .iter()
            .map(|r| {
                let (a, b, t, z) = (
                    <[_; 4]>::from(r.theta_bf_comp_theta0)[i],
                    <[_; 4]>::from(r.theta_bf_comp_true)[i],
                    <[_; 4]>::from(r.theta_true)[i],
                    <[_; 4]>::from(Theta::PAPER_INITIAL)[i],
                );
                (a - b) / (z - t)
            })
            .collect();
        format!("{:.3} / {:.3}", mean(&v), median(&v))
    };
    let _ = writeln!(
        o,
        "| follow ratio (θ_B,F(θ_0) − θ_B,F(θ_true)) / (θ_0 − θ_true), mean / median | {} | {} | {} | {} |\n",
        ratio(0),
        ratio(1),
        ratio(2),
        ratio(3)
    );
    o
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let a = parse_args()?;
    let t0 = Instant::now();
    let mut results = Vec::new();
    for noise in &a.noises {
        for seed in 1..=a.seeds {
            let r = study_drive(noise, seed, &a)?;
            eprintln!(
                "{noise} seed {seed}: {} selected, Ē_p,min {:.3} m, Ē_p(θ_true) {:.3} m, {}/{} QP jobs failed, {:.1} s",
                r.selected, r.e_min_m, r.e_true_m, r.failed_jobs, r.jobs, r.time_s
            );
            results.push(r);
        }
    }
    println!(
        "Study: {} km drives, seeds 1..={}, {} random batches per N, QP solver {}; total {:.0} s.\n",
        a.km,
        a.seeds,
        a.batches,
        a.solver,
        t0.elapsed().as_secs_f64()
    );
    for noise in &a.noises {
        let rs: Vec<&DriveResult> = results.iter().filter(|r| &r.noise == noise).collect();
        if !rs.is_empty() {
            print!("{}", tables(noise, &rs));
        }
    }
    if let Some(p) = &a.json {
        std::fs::write(p, serde_json::to_string_pretty(&results)? + "\n")?;
    }
    Ok(())
}
