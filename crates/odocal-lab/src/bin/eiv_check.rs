//! EIV against batch Gauss-Newton (all segments) and the Cramér–Rao bound
//! on simulated drives, with the covariance recursion held at a reference
//! or following θ (`ResearchOptions::covariance`).
//!
//! Variants (comma separated; default the first four): `held` (covariance
//! held at a reference, η estimated from the production-car start), `follows`
//! (covariance follows θ, η estimated), `held-known` and `follows-known`
//! (the simulator's true noise model, `NoiseModel::from_sim`, fixed),
//! `held-simstart` and `follows-simstart` (η estimated, starting from the
//! true model: right time constants).
//! Per run: errors `[c_e %, c_d mm, t_r %, d mm/(m/s²)]`, reported σ,
//! wall time; then mean ± sd over seeds per preset and variant, and the
//! 24 km timing side by side with batch G-N.

use std::collections::BTreeMap;
use std::time::Instant;

use odocal::eiv::{cramer_rao_bound, estimate, CovarianceMode, EivInput, EivOptions, NoiseModel, ResearchOptions};
use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal::{Drive, Theta};
use odocal_lab::{batch_gn_all as batch_gn, error_scale, Args, Res, Summary};

const USAGE: &str =
    "eiv_check [KM 12] [SEEDS 3] [PRESETS white,paper,high] [VARIANTS held,follows,held-known,follows-known]
    [no-timing]";

fn input_of(d: &Drive) -> EivInput<'_> {
    EivInput::from_drive(d)
}

fn options(variant: &str, noise: &NoiseOptions, ts: f64) -> EivOptions {
    let covariance =
        if variant.starts_with("held") { CovarianceMode::HeldAtReference } else { CovarianceMode::FollowsTheta };
    let research = ResearchOptions { covariance, ..Default::default() };
    if variant.ends_with("known") {
        EivOptions { research, noise: NoiseModel::from_sim(noise, ts), fix_noise: true, ..Default::default() }
    } else if variant.ends_with("simstart") {
        EivOptions { research, noise: NoiseModel::from_sim(noise, ts), ..Default::default() }
    } else {
        EivOptions { research, ..Default::default() }
    }
}

#[derive(Default)]
struct Acc {
    err: Vec<[f64; 4]>,
    sigma: Vec<[f64; 4]>,
    time: Vec<f64>,
}

fn mean_sd(x: &[f64]) -> (f64, f64) {
    let s = Summary::of(x);
    (s.mean, s.sd)
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    let km: f64 = args.pos(0, 12.0)?;
    let seeds: u64 = args.pos(1, 3)?;
    let split = |s: String| s.split(',').map(String::from).collect::<Vec<_>>();
    let presets = split(args.pos(2, "white,paper,high".to_string())?);
    let variants = split(args.pos(3, "held,follows,held-known,follows-known".to_string())?);
    let timing = args.positional().get(4).map(String::as_str) != Some("no-timing");
    args.finish()?;
    let mut acc: BTreeMap<(String, String), Acc> = BTreeMap::new();
    println!(
        "preset seed variant | err [c_e %, c_d mm, t_r %, d mm/(m/s²)] | σ (sandwich t_r) | s | termination, warnings"
    );
    for preset in &presets {
        for seed in 1..=seeds {
            let noise = preset.parse::<NoiseOptions>()?;
            let out = simulate(&SimOptions { length_km: km, noise: noise.clone(), ..SimOptions::paper(seed) })?;
            let d = &out.drive;
            let truth = out.sidecar.theta_true;
            let scale = error_scale(&truth);
            let err = |th: &Theta| -> [f64; 4] {
                let (a, b) = (<[_; 4]>::from(th), <[_; 4]>::from(truth));
                std::array::from_fn(|i| (a[i] - b[i]) * scale[i])
            };
            let sc = |s: &[f64; 4]| -> [f64; 4] { std::array::from_fn(|i| s[i] * scale[i]) };
            let fmt = |a: &[f64; 4]| a.iter().map(|x| format!("{x:+.3}")).collect::<Vec<_>>().join(" ");
            let t = Instant::now();
            let gn = batch_gn(d)?;
            let t_gn = t.elapsed().as_secs_f64();
            println!("{preset:5} {seed} G-N | {} | | {t_gn:.2}", fmt(&err(&gn)));
            let a = acc.entry((preset.clone(), "G-N".into())).or_default();
            a.err.push(err(&gn));
            a.time.push(t_gn);
            let input = input_of(d);
            let true_noise = NoiseModel::from_sim(&noise, d.sample_time_s());
            if let Ok(c) = cramer_rao_bound(&EivInput::from_drive_truth(d)?, &truth, &true_noise, &EivOptions::spec()) {
                println!("{preset:5} {seed} CRB | | {}", fmt(&sc(&c.sigma)));
                acc.entry((preset.clone(), "CRB".into())).or_default().sigma.push(sc(&c.sigma));
            }
            for v in &variants {
                let r = estimate(&input, &gn, &options(v, &noise, d.sample_time_s()))?;
                println!(
                    "{preset:5} {seed} {v} | {} | {} ({:.3}) | {:.2} | {}, evals {:?}, {} warnings, η {:?}",
                    fmt(&err(&r.theta)),
                    fmt(&sc(&r.sigma)),
                    r.sigma_sandwich[2] * scale[2],
                    r.timing_s,
                    r.termination,
                    r.evaluations,
                    r.warnings.len(),
                    r.eta.map(|e| (e * 100.0).round() / 100.0)
                );
                let a = acc.entry((preset.clone(), v.clone())).or_default();
                a.err.push(err(&r.theta));
                a.sigma.push(sc(&r.sigma));
                a.time.push(r.timing_s);
            }
        }
    }
    println!("\nSummary: mean ± sd over seeds (mean reported σ in brackets; CRB rows: mean σ)");
    println!("preset variant | c_e % | c_d mm | t_r % | d mm/(m/s²) | mean s");
    for ((preset, v), a) in &acc {
        let cols: Vec<String> = (0..4)
            .map(|i| {
                let s = if a.sigma.is_empty() {
                    f64::NAN
                } else {
                    a.sigma.iter().map(|s| s[i]).sum::<f64>() / a.sigma.len() as f64
                };
                if a.err.is_empty() {
                    format!("[{s:.3}]")
                } else {
                    let (m, sd) = mean_sd(&a.err.iter().map(|e| e[i]).collect::<Vec<_>>());
                    format!("{m:+.3} ± {sd:.3} [{s:.3}]")
                }
            })
            .collect();
        let tm = if a.time.is_empty() { f64::NAN } else { mean_sd(&a.time).0 };
        println!("{preset:5} {v:13} | {} | {tm:.2}", cols.join(" | "));
    }
    if timing {
        // Speed: one 24 km paper drive, side by side with batch G-N.
        let out = simulate(&SimOptions { length_km: 24.0, ..SimOptions::paper(1) })?;
        let d = &out.drive;
        let t = Instant::now();
        let gn = batch_gn(d)?;
        let t_gn = t.elapsed().as_secs_f64();
        print!("24 km ({} samples): batch G-N {t_gn:.2} s", d.len());
        for v in &variants {
            let r = estimate(&input_of(d), &gn, &options(v, &NoiseOptions::paper(), d.sample_time_s()))?;
            print!("; EIV {v} {:.2} s ({} iterations, evals {:?})", r.timing_s, r.iterations, r.evaluations);
        }
        println!();
    }
    Ok(())
}
