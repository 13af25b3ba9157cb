//! Drift tracking of the online calibrator on simulated drives whose true
//! θ drifts (docs/validation.md, "Simulation: drifting parameters").
//!
//! **Ramp.** Per seed, a 60-minute drive (paper noise) whose c_e falls
//! linearly by `--ramp` (default 0.3 %) over the hour, pushed through the
//! online calibrator (default options, θ_0 the paper's) in 10 s chunks.
//! After the first `--burn-in` seconds (default 300) of informative
//! driving, at every chunk: is the true c_e (at that moment) inside the
//! online ±2σ band; the RMS of the tracking error over the mean reported σ;
//! the lag (the mean error over the ramp's slope: how far behind the
//! estimate runs). The same for a drive without drift as the control, and
//! the other parameters' coverage.
//!
//! **Step.** Per seed, a 30-minute drive A, then a 30-minute drive B whose
//! c_d steps by `--step-mm` (default 1 mm) 10 minutes in, followed by one
//! calibrator (as `odocal follow` replays them); each drive's θ and σ at
//! its end is a history row, and the history's drift flag
//! ([`odocal_history::VehicleHistory::drift`], a change beyond three combined σ)
//! is read between the two rows. The control: drive B without the step
//! (a flag there is a false alarm). `--step-mm` takes a list of step
//! sizes (one table each, then a summary of the flagged counts);
//! `--step-only` skips the ramp.
//!
//! `--random-walk-ce F` and `--random-walk-cd M` set the process noise
//! (per-hour sd of c_e as a fraction, of c_d in m).

use odocal::sim::{simulate, CdStep, DriftOptions, SimOptions};
use odocal::{Drive, Signals, Theta};
use odocal_history::{CalibrationRecord, HistoryRow, VehicleHistory};
use odocal_lab::{Args, Res};
use odocal_online::{Calibrator, OnlineOptions};
use rayon::prelude::*;

const USAGE: &str = "drift_study [--seeds N] [--first-seed S] [--ramp-only | --step-only] [--sigma-factors A,B,C,D] [--ramp FRACTION] [--burn-in S] [--step-mm MM[,MM..]]
    [--random-walk-ce F] [--random-walk-cd M] [--information-scale F]";

/// Samples per pushed chunk (10 s at 40 Hz).
const CHUNK: usize = 400;

fn main() {
    odocal_lab::main_with(run)
}

/// A drive of at least `minutes` with the drift, and its samples in the
/// first `minutes`.
fn drive(seed: u64, minutes: f64, drift: DriftOptions) -> Res<(Drive, SimOptions, usize)> {
    let o = SimOptions { length_km: minutes * 1.2, drift, ..SimOptions::paper(seed) };
    let out = simulate(&o)?;
    let n = ((minutes * 60.0 / out.drive.sample_time_s()) as usize + 1).min(out.drive.len());
    if (n as f64) * out.drive.sample_time_s() < minutes * 60.0 * 0.99 {
        return Err(format!("seed {seed}: the drive lasts less than {minutes} min").into());
    }
    if out.drive.parts().len() != 1 {
        return Err(format!("seed {seed}: a simulated drive should be one part").into());
    }
    Ok((out.drive, o, n))
}

/// Pushes the first `n` samples of `d` as a new drive in chunks; `each`
/// after every chunk with the samples pushed so far.
fn push_first(cal: &mut Calibrator, d: &Drive, n: usize, mut each: impl FnMut(&Calibrator, usize)) -> Res<()> {
    cal.begin_drive();
    for a in (0..n).step_by(CHUNK) {
        let b = (a + CHUNK).min(n);
        let m = d.measured();
        let cols = [&m.px, &m.py, &m.psi, &m.n_rl, &m.n_rr, &m.beta, &m.a_y].map(|c| c[a..b].to_vec());
        let [px, py, psi, n_rl, n_rr, beta, a_y] = cols;
        cal.push(None, &Signals { px, py, psi, n_rl, n_rr, beta, a_y })?;
        each(cal, b);
    }
    Ok(())
}

/// The online options of the command line.
fn options(a: &Knobs) -> OnlineOptions {
    let mut o = OnlineOptions::default();
    if let Some(f) = a.rw_ce {
        o.random_walk.c_e_relative = f;
    }
    if let Some(m) = a.rw_cd {
        o.random_walk.c_d_m = m;
    }
    if let Some(f) = a.information_scale {
        o.information_scale = f;
    }
    o
}

struct Knobs {
    rw_ce: Option<f64>,
    rw_cd: Option<f64>,
    information_scale: Option<f64>,
    burn_in_s: f64,
}

/// One ramp run: per parameter the fraction of evaluated times inside ±2σ,
/// and for c_e the RMS error, mean σ and mean error.
struct RampRun {
    covered: [f64; 4],
    rms_ce: f64,
    mean_sigma_ce: f64,
    mean_err_ce: f64,
    evaluated: usize,
    start_s: f64,
    /// Per parameter, at every evaluated time: (error, σ).
    trace: [Vec<(f64, f64)>; 4],
}

fn ramp_run(seed: u64, ramp: f64, k: &Knobs) -> Res<RampRun> {
    let drift = DriftOptions { c_e_relative_per_hour: -ramp, c_d_step: None };
    let (d, o, len) = drive(seed, 60.0, drift)?;
    let ts = d.sample_time_s();
    let mut cal = Calibrator::new(Theta::PAPER_INITIAL, None, ts, options(k))?;
    let (mut inside, mut n, mut sq, mut sig, mut err) = ([0usize; 4], 0usize, 0.0, 0.0, 0.0);
    let mut start_s = f64::NAN;
    let mut trace: [Vec<(f64, f64)>; 4] = Default::default();
    push_first(&mut cal, &d, len, |cal, b| {
        let st = cal.status();
        if st.informative_time_s < k.burn_in_s {
            return;
        }
        if start_s.is_nan() {
            start_s = (b - 1) as f64 * ts;
        }
        let truth = <[_; 4]>::from(o.drift.theta_at(&o.theta_true, (b - 1) as f64 * ts));
        let (th, s) = (<[_; 4]>::from(st.theta), <[_; 4]>::from(st.sigma));
        for i in 0..4 {
            inside[i] += usize::from((th[i] - truth[i]).abs() <= 2.0 * s[i]);
            trace[i].push((th[i] - truth[i], s[i]));
        }
        let e = th[0] - truth[0];
        (n, sq, sig, err) = (n + 1, sq + e * e, sig + s[0], err + e);
    })?;
    if n == 0 {
        return Err(format!("seed {seed}: fewer than {} s of informative driving", k.burn_in_s).into());
    }
    let nf = n as f64;
    Ok(RampRun {
        covered: inside.map(|c| c as f64 / nf),
        rms_ce: (sq / nf).sqrt(),
        mean_sigma_ce: sig / nf,
        mean_err_ce: err / nf,
        evaluated: n,
        start_s,
        trace,
    })
}

fn row(id: i64, theta: Theta, sigma: Theta) -> HistoryRow {
    HistoryRow {
        id,
        recorded_at: format!("drive {id}"),
        odocal_version: String::new(),
        record: CalibrationRecord { sigma: sigma.into(), ..CalibrationRecord::new("sim", "", "online", theta) },
    }
}

/// One step run: the c_d change between the two rows, its combined σ and
/// whether the history flags c_d.
struct StepRun {
    change: f64,
    combined: f64,
    flagged: bool,
}

fn step_run(seed: u64, step_m: f64, k: &Knobs) -> Res<StepRun> {
    let (a, _, na) = drive(seed + 100, 30.0, DriftOptions::default())?;
    let at_s = 600.0;
    let step = (step_m != 0.0).then_some(CdStep { change_m: step_m, at_s });
    let (b, _, nb) = drive(seed + 200, 30.0, DriftOptions { c_e_relative_per_hour: 0.0, c_d_step: step })?;
    let ts = a.sample_time_s();
    let mut cal = Calibrator::new(Theta::PAPER_INITIAL, None, ts, options(k))?;
    push_first(&mut cal, &a, na, |_, _| {})?;
    let st = cal.status();
    let row_a = row(1, st.theta, st.sigma);
    push_first(&mut cal, &b, nb, |_, _| {})?;
    let st = cal.status();
    let row_b = row(2, st.theta, st.sigma);
    let flags = VehicleHistory::of_rows("sim", vec![row_a.clone(), row_b.clone()], None).drift;
    let (sa, sb) = (row_a.record.sigma.c_d.unwrap_or(0.0), row_b.record.sigma.c_d.unwrap_or(0.0));
    Ok(StepRun {
        change: row_b.record.theta.c_d - row_a.record.theta.c_d,
        combined: (sa * sa + sb * sb).sqrt(),
        flagged: flags.iter().any(|f| f.parameter == "c_d"),
    })
}

/// Prints the runs; `lag s` is the mean error (minus the same seed's mean
/// error without drift, `base`, which takes out the estimator's own bias)
/// over the ramp's slope.
fn print_ramp(label: &str, runs: &[RampRun], base: &[RampRun], slope_per_s: f64, factors: [f64; 4]) {
    println!("\n{label}");
    print_errors(runs, factors);
    println!(
        "{:>4} {:>7} {:>6} {:>6} {:>6} {:>6} {:>10} {:>10} {:>10} {:>7} {:>8}",
        "seed", "from s", "c_e", "c_d", "t_r", "d", "mean err", "rms c_e", "mean σ", "rms/σ", "lag s"
    );
    for (i, r) in runs.iter().enumerate() {
        let lag = if slope_per_s == 0.0 { f64::NAN } else { -(r.mean_err_ce - base[i].mean_err_ce) / slope_per_s };
        println!(
            "{:>4} {:>7.0} {:>5.1}% {:>5.1}% {:>5.1}% {:>5.1}% {:>10.3e} {:>10.3e} {:>10.3e} {:>7.2} {:>8.0}",
            i + 1,
            r.start_s,
            100.0 * r.covered[0],
            100.0 * r.covered[1],
            100.0 * r.covered[2],
            100.0 * r.covered[3],
            r.mean_err_ce,
            r.rms_ce,
            r.mean_sigma_ce,
            r.rms_ce / r.mean_sigma_ce,
            lag
        );
    }
    let n = runs.iter().map(|r| r.evaluated).sum::<usize>() as f64;
    let w = |f: &dyn Fn(&RampRun) -> f64| runs.iter().map(|r| f(r) * r.evaluated as f64).sum::<f64>() / n;
    let rms = w(&|r| r.rms_ce * r.rms_ce).sqrt();
    let sigma = w(&|r| r.mean_sigma_ce);
    let base_err = base.iter().map(|r| r.mean_err_ce * r.evaluated as f64).sum::<f64>() / n;
    let lag = if slope_per_s == 0.0 { f64::NAN } else { -(w(&|r| r.mean_err_ce) - base_err) / slope_per_s };
    println!(
        " all         {:>5.1}% {:>5.1}% {:>5.1}% {:>5.1}% {:>10.3e} {:>10.3e} {:>10.3e} {:>7.2} {:>8.0}",
        100.0 * w(&|r| r.covered[0]),
        100.0 * w(&|r| r.covered[1]),
        100.0 * w(&|r| r.covered[2]),
        100.0 * w(&|r| r.covered[3]),
        w(&|r| r.mean_err_ce),
        rms,
        sigma,
        rms / sigma,
        lag
    );
}

/// Per parameter over all seeds and evaluated times: mean error, RMS
/// error, mean and median σ, RMS ÷ mean σ, coverage of ±2σ, median
/// half-width ÷ RMS, and the factor on σ that 90 % coverage would need;
/// σ multiplied by `factors` (`--sigma-factors`) first.
fn print_errors(runs: &[RampRun], factors: [f64; 4]) {
    println!(
        "{:>4} {:>11} {:>11} {:>11} {:>11} {:>7} {:>7} {:>9} {:>8}",
        "par", "mean err", "rms err", "mean σ", "median σ", "rms/σ", "±2σ", "2σmed/rms", "k for 90"
    );
    for (i, name) in ["c_e", "c_d", "t_r", "d"].iter().enumerate() {
        let all: Vec<(f64, f64)> =
            runs.iter().flat_map(|r| r.trace[i].iter().map(|p| (p.0, p.1 * factors[i]))).collect();
        let n = all.len() as f64;
        let mean = all.iter().map(|p| p.0).sum::<f64>() / n;
        let rms = (all.iter().map(|p| p.0 * p.0).sum::<f64>() / n).sqrt();
        let msig = all.iter().map(|p| p.1).sum::<f64>() / n;
        let mut sig: Vec<f64> = all.iter().map(|p| p.1).collect();
        sig.sort_by(f64::total_cmp);
        let med = sig[sig.len() / 2];
        let cov = all.iter().filter(|p| p.0.abs() <= 2.0 * p.1).count() as f64 / n;
        let mut z: Vec<f64> = all.iter().map(|p| p.0.abs() / (2.0 * p.1)).collect();
        z.sort_by(f64::total_cmp);
        let k90 = z[((0.9 * n) as usize).min(z.len() - 1)];
        println!(
            "{name:>4} {mean:>11.3e} {rms:>11.3e} {msig:>11.3e} {med:>11.3e} {:>7.2} {:>6.1}% {:>9.2} {k90:>8.2}",
            rms / msig,
            100.0 * cov,
            2.0 * med / rms
        );
    }
}

/// The ramp's tables: with the drift and the same seeds without.
fn ramp_tables(ids: &[u64], ramp: f64, k: &Knobs, factors: [f64; 4]) -> Res<()> {
    let slope = -ramp * Theta::SIM_DEFAULT_TRUE.c_e / 3600.0;
    let flat =
        ids.par_iter().map(|&s| ramp_run(s, 0.0, k).map_err(|e| e.to_string())).collect::<Result<Vec<_>, String>>();
    let flat = flat.map_err(|e| e.to_string())?;
    let ramps =
        ids.par_iter().map(|&s| ramp_run(s, ramp, k).map_err(|e| e.to_string())).collect::<Result<Vec<_>, String>>();
    let ramps = ramps.map_err(|e| e.to_string())?;
    print_ramp(
        &format!(
            "c_e falling {:.2} % over 60 min: share of time inside ±2σ (after {} s informative)",
            ramp * 100.0,
            k.burn_in_s
        ),
        &ramps,
        &flat,
        slope,
        factors,
    );
    print_ramp("control: no drift (the same seeds)", &flat, &flat, 0.0, factors);
    Ok(())
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &["ramp-only", "step-only"])?;
    let seeds: u64 = a.get("seeds", 6)?;
    let first_seed: u64 = a.get("first-seed", 1)?;
    let ramp_only = a.flag("ramp-only");
    let step_only = a.flag("step-only");
    let factors: Vec<f64> = match a.opt::<String>("sigma-factors")? {
        Some(v) => v.split(',').map(str::parse).collect::<Result<_, _>>()?,
        None => vec![1.0; 4],
    };
    let factors: [f64; 4] = factors.try_into().map_err(|_| "--sigma-factors takes four numbers")?;
    let ramp: f64 = a.get("ramp", 0.003)?;
    let steps_mm: Vec<f64> = match a.opt::<String>("step-mm")? {
        Some(v) => v.split(',').map(str::parse).collect::<Result<_, _>>()?,
        None => vec![1.0],
    };
    let k = Knobs {
        burn_in_s: a.get("burn-in", 300.0)?,
        rw_ce: a.opt("random-walk-ce")?,
        rw_cd: a.opt("random-walk-cd")?,
        information_scale: a.opt("information-scale")?,
    };
    a.finish()?;
    let o = options(&k);
    println!(
        "online options: random walk c_e {:.2e}/√h (relative), c_d {:.2e} m/√h; information scale {}",
        o.random_walk.c_e_relative, o.random_walk.c_d_m, o.information_scale
    );
    let ids: Vec<u64> = (first_seed..first_seed + seeds).collect();
    if !step_only {
        ramp_tables(&ids, ramp, &k, factors)?;
    }
    if ramp_only {
        return Ok(());
    }
    let mut summary = Vec::new();
    let cases = steps_mm.iter().map(|&mm| (format!("c_d step of {mm} mm 10 min into drive B"), mm));
    for (label, mm) in cases.chain([("control: no step".to_string(), 0.0)]) {
        let runs = ids
            .par_iter()
            .map(|&s| step_run(s, mm * 1e-3, &k).map_err(|e| e.to_string()))
            .collect::<Result<Vec<_>, String>>();
        let runs = runs.map_err(|e| e.to_string())?;
        println!("\n{label}: the history's drift flag between the rows of drive A and drive B");
        println!("{:>4} {:>10} {:>10} {:>6} {:>8}", "seed", "Δc_d mm", "comb σ mm", "×σ", "flagged");
        for (s, r) in ids.iter().zip(&runs) {
            println!(
                "{:>4} {:>10.3} {:>10.3} {:>6.1} {:>8}",
                s,
                r.change * 1e3,
                r.combined * 1e3,
                r.change.abs() / r.combined,
                if r.flagged { "yes" } else { "no" }
            );
        }
        let flagged = runs.iter().filter(|r| r.flagged).count();
        println!(" flagged: {} of {}", flagged, runs.len());
        let mean_combined = runs.iter().map(|r| r.combined).sum::<f64>() / runs.len() as f64;
        summary.push((mm, flagged, runs.len(), mean_combined));
    }
    println!("\nstep mm  flagged  mean comb σ mm  step/(3·comb σ)");
    for (mm, f, n, c) in summary {
        println!("{:>7} {:>4} of {:<3} {:>14.3} {:>16.2}", mm, f, n, c * 1e3, mm * 1e-3 / (3.0 * c));
    }
    Ok(())
}
