//! Does the σ a result reports cover the next drive? (docs/validation.md,
//! "Coverage of the reported σ").
//!
//! The six test-track runs of 2024-08-05, each calibrated alone with the
//! default (`odocal calibrate RUN.toml`). For each run and parameter, the
//! run's 95 % interval θ̂ ± 1.96 σ (the σ that stands for the result, JSON
//! `sigma`: the σ for the next drive) must contain the pooled estimate of
//! the other five runs (their mean) in ≥ 80 % of run × parameter cases,
//! while the median half-width stays ≤ 2.5 × the observed between-run sd
//! (sample sd of the six estimates). The between-drive prior
//! (`odocal::pooling::BETWEEN_DRIVE_PRIOR`) was designed on the three
//! earliest runs (14-45-26, 15-28-33, 16-06-28: the sd of their estimates
//! and their within-drive σ, printed here as "design spread") and is
//! confirmed on the other three (16-47-33,
//! 17-45-46, 18-01-26): the table reports both halves separately, and the
//! same with the within-drive σ (`sigma_within_drive`) for comparison.
//!
//! Then the highway van (examples/psu-mapping-van, 2024-07-11) split in
//! halves: each half calibrated alone, its interval against the other
//! half's estimate. Last, the DerSimonian–Laird pooling of the six runs
//! (`odocal::pooling::PooledDrives`, within-drive σ) with its τ.

use odocal::pooling::{PooledDrives, BETWEEN_DRIVE_PRIOR};
use odocal::{calibrate, Calibration, CalibrationOptions, CalibrationReport, Drive, Holdout, Theta};
use odocal_lab::{load, median, testtrack_runs, Args, ReadingsNoise, Res, Table, PARAMETERS, VAN_MANIFEST};

const USAGE: &str = concat!(
    "sigma_coverage [--no-van] [--json-out DIR] [--lateral-from-readings] [--a-y-held-from-readings]\n\n",
    odocal_lab::readings_noise_usage!()
);

/// Per parameter: the unit's scale for printing and its name.
const SHOW: [(f64, &str); 4] = [(1.0, "m"), (1e3, "mm"), (1.0, "m"), (1e3, "mm/(m/s²)")];

fn main() {
    odocal_lab::main_with(run)
}

struct Fit {
    name: String,
    theta: [f64; 4],
    next: [Option<f64>; 4],
    within: [Option<f64>; 4],
    /// The within-drive part of the next-drive σ (for a parameter EIV held
    /// at its start's estimate: the start's σ).
    within_part: [Option<f64>; 4],
    verdict: String,
    outcome: String,
}

fn fit(name: &str, r: &CalibrationReport) -> Fit {
    let outcome = match odocal_lab::report_json::eiv_part(r) {
        Some(d) if d.fell_back() => "BatchGnFallback".to_string(),
        Some(_) => "Eiv".to_string(),
        None => r.method.clone(),
    };
    Fit {
        name: name.to_string(),
        theta: <[_; 4]>::from(r.theta),
        next: <[_; 4]>::from(r.result_sigma()),
        within: <[_; 4]>::from(r.within_drive_sigma()),
        within_part: r.next_drive_sigma().map_or([None; 4], |n| n.within_drive),
        verdict: r.verdict.level.to_string(),
        outcome,
    }
}

fn sd(x: &[f64]) -> f64 {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len() - 1) as f64).sqrt()
}

fn run() -> Res<()> {
    let [lateral, a_y_held] = ReadingsNoise::SWITCHES;
    let mut a = Args::parse(USAGE, &["no-van", lateral, a_y_held])?;
    let van = !a.flag("no-van");
    let json_out: Option<String> = a.opt("json-out")?;
    let readings_noise = ReadingsNoise::from_args(&a);
    a.finish()?;
    let opts = CalibrationOptions::default();
    let for_drive = |d: &Drive| {
        let mut o = opts.clone();
        readings_noise.apply(&mut o, d);
        o
    };
    let runs = testtrack_runs()?;
    let mut fits = Vec::new();
    for (name, d) in &runs {
        let r = calibrate(d, &for_drive(d))?;
        eprintln!("{name}: {} ({})", r.verdict.level, r.method);
        if let Some(dir) = &json_out {
            write_json(dir, name, &r)?;
        }
        fits.push(fit(name, &r));
    }
    print_runs(&fits);
    let all_sd: [f64; 4] = std::array::from_fn(|i| sd(&fits.iter().map(|f| f.theta[i]).collect::<Vec<_>>()));
    print_design(&fits[..3]);
    println!("### Coverage of the other runs' pooled estimate (95 % interval, ±1.96 σ)\n");
    let mut t = Table::new(&["runs", "σ", "c_e: covered · half-width/sd", "c_d", "t_r", "d", "all four covered"]);
    for (label, range) in
        [("design (14-45-26, 15-28-33, 16-06-28)", 0..3), ("confirm (16-47-33, 17-45-46, 18-01-26)", 3..6)]
    {
        for (which, next) in [("next drive (`sigma`)", true), ("within drive (`sigma_within_drive`)", false)] {
            let mut row = vec![label.to_string(), which.to_string()];
            let mut hit_all = (0, 0);
            for (p, s) in all_sd.iter().enumerate() {
                let (mut hit, mut n, mut half) = (0, 0, Vec::new());
                for i in range.clone() {
                    let others: Vec<f64> = (0..6).filter(|&j| j != i).map(|j| fits[j].theta[p]).collect();
                    let pooled = others.iter().sum::<f64>() / others.len() as f64;
                    let sigma = if next { fits[i].next[p] } else { fits[i].within[p] };
                    n += 1;
                    if let Some(sg) = sigma {
                        half.push(1.96 * sg);
                        hit += usize::from((fits[i].theta[p] - pooled).abs() <= 1.96 * sg);
                    }
                }
                hit_all = (hit_all.0 + hit, hit_all.1 + n);
                let ratio = if half.is_empty() { f64::NAN } else { median(&half) / s };
                row.push(format!("{hit}/{n} · {ratio:.2}"));
            }
            row.push(format!("{}/{} ({:.0} %)", hit_all.0, hit_all.1, 100.0 * hit_all.0 as f64 / hit_all.1 as f64));
            t.row(row);
        }
    }
    println!("{t}");
    println!(
        "Between-run sd over the six runs: c_e {:.3e} m, c_d {:.3} mm, t_r {:.3e} m, d {:.3} mm/(m/s²).\n",
        all_sd[0],
        all_sd[1] * 1e3,
        all_sd[2],
        all_sd[3] * 1e3
    );
    print_pooling(&fits);
    if van {
        van_halves(&for_drive, json_out.as_deref())?;
    }
    Ok(())
}

fn print_runs(fits: &[Fit]) {
    println!("### The six runs, default calibration\n");
    let mut t = Table::new(&["run", "result", "verdict", "c_e m", "c_d mm", "t_r m", "d mm/(m/s²)"]);
    for f in fits {
        let mut row = vec![f.name.clone(), f.outcome.clone(), f.verdict.clone()];
        for (p, (scale, _)) in SHOW.iter().enumerate() {
            let s = |x: Option<f64>| x.map_or("held".to_string(), |x| format!("{:.2e}", x * scale));
            row.push(format!("{:.5} ± {} (within {})", f.theta[p] * scale, s(f.next[p]), s(f.within[p])));
        }
        t.row(row);
    }
    println!("{t}");
}

/// Writes the report `r` of run `name` as `DIR/NAME.json` (for offline
/// study of the σ's parts, JSON `next_drive_sigma`).
fn write_json(dir: &str, name: &str, r: &CalibrationReport) -> Res<()> {
    std::fs::create_dir_all(dir)?;
    std::fs::write(std::path::Path::new(dir).join(format!("{name}.json")), serde_json::to_string_pretty(r)?)?;
    Ok(())
}

/// The design runs' spread, their within-drive σ and the between-drive σ
/// net of it, against the prior the library states.
fn print_design(design: &[Fit]) {
    let sds: [f64; 4] = std::array::from_fn(|i| sd(&design.iter().map(|f| f.theta[i]).collect::<Vec<_>>()));
    let ce = design.iter().map(|f| f.theta[0]).sum::<f64>() / design.len() as f64;
    let tr = design.iter().map(|f| f.theta[2]).sum::<f64>() / design.len() as f64;
    let scale = [ce, ce, tr, tr];
    let rel: [f64; 4] = std::array::from_fn(|i| sds[i] / scale[i]);
    // RMS of each run's within-drive part, relative to its own θ.
    let within: [f64; 4] = std::array::from_fn(|i| {
        let v: Vec<f64> = design
            .iter()
            .filter_map(|f| {
                let own = if i < 2 { f.theta[0] } else { f.theta[2] };
                f.within_part[i].map(|w| (w / own).powi(2))
            })
            .collect();
        (v.iter().sum::<f64>() / v.len() as f64).sqrt()
    });
    let net: [f64; 4] = std::array::from_fn(|i| (rel[i].powi(2) - within[i].powi(2)).max(0.0).sqrt());
    let theta: Vec<Theta> = design.iter().map(|f| Theta::from(f.theta)).collect();
    let pooled = PooledDrives::new("eiv".into(), theta, design.iter().map(|f| f.within_part).collect());
    let tau: [f64; 4] = std::array::from_fn(|i| pooled.params[i].map_or(f64::NAN, |p| p.tau / scale[i]));
    let p = BETWEEN_DRIVE_PRIOR;
    let prior_net: [f64; 4] = std::array::from_fn(|i| {
        let s = [p.c_e, p.c_d, p.t_r, p.d][i];
        (s * s - p.within[i] * p.within[i]).max(0.0).sqrt()
    });
    println!("### Design spread (three earliest runs) and the library's prior\n");
    let mut t = Table::new(&["", "c_e (of c_e)", "c_d (of c_e)", "t_r (of t_r)", "d (of t_r, per m/s²)"]);
    let mut row = |label: &str, v: &[f64; 4]| {
        t.row(std::iter::once(label.to_string()).chain(v.iter().map(|r| format!("{r:.2e}"))));
    };
    row("design runs' spread s (sd of the estimates), relative", &rel);
    row("design runs' within-drive σ σ̄_w (RMS), relative", &within);
    row("τ̂ = √max(0, s² − σ̄_w²), relative", &net);
    row("design runs' τ (DerSimonian–Laird on their within-drive σ), relative", &tau);
    row("BETWEEN_DRIVE_PRIOR: spread (the floor)", &[p.c_e, p.c_d, p.t_r, p.d]);
    row("BETWEEN_DRIVE_PRIOR: within-drive σ", &p.within);
    row("BETWEEN_DRIVE_PRIOR: τ̂", &prior_net);
    println!("{t}");
}

/// DerSimonian–Laird over the six runs with their within-drive σ.
fn print_pooling(fits: &[Fit]) {
    let theta: Vec<Theta> = fits.iter().map(|f| Theta::from(f.theta)).collect();
    let sigma: Vec<[Option<f64>; 4]> = fits.iter().map(|f| f.within_part).collect();
    let p = PooledDrives::new("eiv".into(), theta, sigma);
    println!("### Random-effects pooling of the six runs (DerSimonian–Laird, within-drive σ)\n");
    let mut t = Table::new(&["parameter", "pooled", "σ of the pooled mean", "τ (between-drive)", "Q", "drives"]);
    for (i, name) in PARAMETERS.iter().enumerate() {
        let (scale, unit) = SHOW[i];
        match p.params[i] {
            Some(r) => t.row([
                format!("{name} ({unit})"),
                format!("{:.5}", r.mean * scale),
                format!("{:.2e}", r.mean_sigma * scale),
                format!("{:.2e}", r.tau * scale),
                format!("{:.0}", r.q),
                r.drives.to_string(),
            ]),
            None => t.row([format!("{name} ({unit})"), "–".into(), "–".into(), "–".into(), "–".into(), "–".into()]),
        }
    }
    println!("{t}");
}

/// The van's halves: each half's interval against the other half's θ,
/// both halves with the whole drive's options (`for_drive`).
fn van_halves(for_drive: &dyn Fn(&Drive) -> CalibrationOptions, json_out: Option<&str>) -> Res<()> {
    let d = load(VAN_MANIFEST)?;
    let opts = &for_drive(&d);
    let half = |name: &str, holdout: Holdout| -> Res<Fit> {
        let r = Calibration { holdout: Some(&holdout), ..Calibration::new(&d, opts) }.run()?;
        if let Some(dir) = json_out {
            write_json(dir, &format!("van-{}", name.replace(' ', "-")), &r)?;
        }
        Ok(fit(name, &r))
    };
    // Holdout::FirstHalf holds the first half out: the fit is on the second.
    let second = half("second half", Holdout::FirstHalf)?;
    let first = half("first half", Holdout::SecondHalf)?;
    println!("### Highway van (07-11) in halves: each half's 95 % interval against the other half's estimate\n");
    let mut t = Table::new(&["fitted on", "result", "verdict", "c_e", "c_d", "t_r", "d"]);
    for (a, b) in [(&first, &second), (&second, &first)] {
        let mut row = vec![a.name.clone(), a.outcome.clone(), a.verdict.clone()];
        for p in 0..4 {
            let z = |s: Option<f64>| {
                s.map_or("held".to_string(), |s| format!("{:.1}", (a.theta[p] - b.theta[p]).abs() / s))
            };
            row.push(format!("{} σ (within: {} σ)", z(a.next[p]), z(a.within[p])));
        }
        t.row(row);
    }
    println!("{t}");
    println!("Covered when the distance is at most 1.96 σ.\n");
    Ok(())
}
