//! Where EIV's excess spread over the Cramér–Rao bound comes from: the
//! estimator itself, or the simulator's departures from the filter's
//! model? In the *replicate world* of the parametric bootstrap the data
//! are drawn from the filter's own model: at the fitted θ̂ with the fitted
//! noise model, on the drive's own inputs. There the noise model is known
//! and exact (up to the filter's linearisation), so the Cramér–Rao bound of
//! that world, [`cramer_rao_bound`] at (θ̂, fitted noise), is the bound the
//! replicate fits can be judged against. If they are far from it, the excess
//! is the estimator's (the profile cost J uses the innovations' mean, not
//! their size); if they reach it, it is the mismatch.
//!
//! Defaults: `high`, 10 seeds, 10 replicates, 12 km. Per drive: the fit
//! (η estimated, uncorrected), B replicate fits with the fitted noise model
//! held, and the bound of the replicate world (full Fisher and mean-only).
//! Pooled over drives and replicates: RMS of (replicate − θ̂) against the
//! root mean square of each bound. Every random choice is seeded (the drive
//! by its seed, the replicates by the same seed).

use odocal::eiv::{bootstrap, cramer_rao_bound, estimate, BootstrapOptions, EivInput, EivOptions};
use odocal_lab::{batch_gn_all, simulate_preset, Args, Res, PARAMETERS};

const USAGE: &str = "eiv_efficiency [PRESET high] [SEEDS 10] [REPLICATES 10] [KM 12]";

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    let preset: String = args.pos(0, "high".to_string())?;
    let seeds: u64 = args.pos(1, 10)?;
    let replicates: usize = args.pos(2, 10)?;
    let km: f64 = args.pos(3, 12.0)?;
    args.finish()?;
    // Pooled sums: squared replicate errors, squared bounds (full, mean-only), counts.
    let (mut err2, mut full2, mut mean2) = ([0.0f64; 4], [0.0f64; 4], [0.0f64; 4]);
    let (mut n_rep, mut n_drive) = (0usize, 0usize);
    println!("preset {preset}, {km} km, seeds 1..={seeds}, {replicates} replicates each");
    println!("seed | replicate sd / full-Fisher CRB of the replicate world (c_e, c_d, t_r, d)");
    for seed in 1..=seeds {
        let out = simulate_preset(&preset, km, seed)?;
        let d = &out.drive;
        let input = EivInput::from_drive(d);
        let start = batch_gn_all(d)?;
        let opts = EivOptions::default();
        let fit = estimate(&input, &start, &opts)?;
        // The replicate world: θ̂ and the fitted noise model, known.
        let held = EivOptions { noise: fit.noise, fix_noise: true, ..opts.clone() };
        let boot = bootstrap(&input, &fit, &held, &BootstrapOptions { replicates, seed, ..Default::default() })?;
        // The replicate world's true inputs are the drive's measured ones
        // (`BootstrapInputs::Measured`), so its bound is linearised along them.
        let crb = cramer_rao_bound(&input, &fit.theta, &fit.noise, &held)?;
        let hat = <[_; 4]>::from(fit.theta);
        let mut sd = [0.0f64; 4];
        for t in &boot.replicates {
            let a = <[_; 4]>::from(t);
            for i in 0..4 {
                let e = a[i] - hat[i];
                err2[i] += e * e;
                sd[i] += e * e;
            }
        }
        let n = boot.replicates.len();
        n_rep += n;
        n_drive += 1;
        for i in 0..4 {
            full2[i] += crb.sigma[i] * crb.sigma[i];
            mean2[i] += crb.sigma_mean_only[i] * crb.sigma_mean_only[i];
        }
        let ratio: Vec<String> =
            (0..4).map(|i| format!("{:.2}", (sd[i] / n.max(1) as f64).sqrt() / crb.sigma[i])).collect();
        println!("{seed} | {} ({n} replicates)", ratio.join(", "));
    }
    if n_rep == 0 {
        return Err("no replicate could be fitted".into());
    }
    println!("\npooled over {n_drive} drives and {n_rep} replicates:");
    println!("| parameter | RMS(replicate − θ̂) | RMS / full-Fisher CRB | RMS / mean-only CRB |");
    println!("|---|---:|---:|---:|");
    for i in 0..4 {
        let rms = (err2[i] / n_rep as f64).sqrt();
        let (f, m) = ((full2[i] / n_drive as f64).sqrt(), (mean2[i] / n_drive as f64).sqrt());
        println!("| {} | {rms:.4e} | {:.2} | {:.2} |", PARAMETERS[i], rms / f, rms / m);
    }
    Ok(())
}
