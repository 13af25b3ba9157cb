//! Diagnostic of c_e's uncertainty under coloured common-mode wheel noise
//! (the measurements behind `CovarianceEstimate`'s docs): per seed, c_e's
//! error against each reported
//! σ (H⁻¹, sandwich, Fisher) for the known and the estimated noise model and
//! variants, where η₁ (the common-mode scale) goes, and the marginal
//! likelihood M profiled over η₁ with the other scales held at the fitted
//! values (`--profile`). `CECOV_HISTORY=1` prints every iteration.

use odocal::eiv::{estimate, EivInput, EivOptions, EivReport, NoiseModel};
use odocal::sim::{simulate, SimOptions};
use odocal_lab::{batch_gn_all, noise_preset, Args, Res};

const USAGE: &str = "cecov_diag [--km 12] [--seeds 4] [--first-seed 1] [--preset coloured] [--profile]
    [--variants known,est,est-simtau,est-fix1]   (also est-from-sim, est-fix1-simtau)";

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &["profile"])?;
    let km: f64 = a.get("km", 12.0)?;
    let seeds: u64 = a.get("seeds", 4)?;
    let first_seed: u64 = a.get("first-seed", 1)?;
    let preset: String = a.get("preset", "coloured".to_string())?;
    let profile = a.flag("profile");
    let variants = a.list("variants", &["known", "est", "est-simtau", "est-fix1"]);
    a.finish()?;
    let noise = noise_preset(&preset)?;
    // Per variant: (c_e error %, σ_H %, σ_sandwich %, σ_Fisher %).
    let mut rows: Vec<(String, Vec<[f64; 4]>)> = Vec::new();
    for seed in first_seed..first_seed + seeds {
        let sim = simulate(&SimOptions { length_km: km, noise: noise.clone(), ..SimOptions::paper(seed) })?;
        let d = &sim.drive;
        let truth = sim.sidecar.theta_true;
        let gn = batch_gn_all(d)?;
        let input = EivInput::from_drive(d);
        let sim_noise = NoiseModel::from_sim(&noise, d.sample_time_s());
        let pc = NoiseModel::PRODUCTION_CAR;
        let simtau = NoiseModel {
            wheel_common_time_constant_s: sim_noise.wheel_common_time_constant_s,
            wheel_differential_time_constant_s: sim_noise.wheel_differential_time_constant_s,
            ..pc
        };
        let ce = |r: &EivReport| (r.theta.c_e - truth.c_e) / truth.c_e * 100.0;
        let pct = |s: f64| s / truth.c_e * 100.0;
        let show = |label: &str, r: &EivReport, rows: &mut Vec<(String, Vec<[f64; 4]>)>| {
            let e = ce(r);
            let (sh, ss, sf) = (pct(r.sigma[0]), pct(r.sigma_block[0]), pct(r.sigma_fisher[0]));
            let hz = r.halves.as_ref().map(|h| h.z[0]).unwrap_or(f64::NAN);
            println!(
                "  {label:16} c_e {e:+.4}% σ_H {sh:.4} σ_B {ss:.4} σ_F {sf:.4} z_H {:+.1} | t_r {:+.3}% | η [{}] ησ [{}] \
                 | halves z_c_e {hz:+.1} | M {:.2} it {} {:.1}s warn {}",
                e / sh,
                (r.theta.t_r - truth.t_r) / truth.t_r * 100.0,
                r.eta.iter().map(|x| format!("{x:+.2}")).collect::<Vec<_>>().join(" "),
                r.eta_sigma.iter().map(|x| format!("{x:.2}")).collect::<Vec<_>>().join(" "),
                r.final_cost,
                r.iterations,
                r.timing_s,
                r.warnings.len()
            );
            for w in &r.warnings {
                println!("      warning: {w}");
            }
            if std::env::var("CECOV_HISTORY").is_ok() {
                for h in r.passes.iter().flat_map(|p| p.history.iter()) {
                    println!(
                        "      it: c_e {:+.4}% η [{}] cost {:.2} step/σ {:.3} λ {}",
                        (h.theta.c_e - truth.c_e) / truth.c_e * 100.0,
                        h.eta.iter().map(|x| format!("{x:+.2}")).collect::<Vec<_>>().join(" "),
                        h.cost,
                        h.step_over_sigma,
                        h.step_factor
                    );
                }
            }
            let i = match rows.iter().position(|(k, _)| k == label) {
                Some(i) => i,
                None => {
                    rows.push((label.to_string(), Vec::new()));
                    rows.len() - 1
                }
            };
            rows[i].1.push([e, sh, ss, sf]);
        };
        println!("{preset} {seed}: G-N c_e {:+.4}%", (gn.c_e - truth.c_e) / truth.c_e * 100.0);
        let base = EivOptions::default();
        let mut est_report: Option<EivReport> = None;
        for v in &variants {
            let opts = match v.as_str() {
                "known" => EivOptions { noise: sim_noise, fix_noise: true, ..base.clone() },
                "est" => base.clone(),
                "est-simtau" => EivOptions { noise: simtau, ..base.clone() },
                "est-from-sim" => EivOptions { noise: sim_noise, ..base.clone() },
                "est-fix1" | "est-fix1-simtau" => {
                    // The fitted model of `est` with σ_c set to the simulator's
                    // (and τ_c too with -simtau), everything held.
                    let Some(r) = &est_report else { continue };
                    let mut nm = r.noise;
                    nm.wheel_common_rel_sigma = sim_noise.wheel_common_rel_sigma;
                    if v == "est-fix1-simtau" {
                        nm.wheel_common_time_constant_s = sim_noise.wheel_common_time_constant_s;
                    }
                    EivOptions { noise: nm, fix_noise: true, ..base.clone() }
                }
                other => return Err(format!("unknown variant {other}").into()),
            };
            let r = estimate(&input, &gn, &opts)?;
            show(v, &r, &mut rows);
            if v == "est" {
                est_report = Some(r);
            }
        }
        if profile {
            if let Some(r) = &est_report {
                for tau in [pc.wheel_common_time_constant_s, sim_noise.wheel_common_time_constant_s] {
                    for sc in [0.0, 0.0002, 0.0005, 0.001, 0.002, 0.004] {
                        let mut nm = r.noise;
                        nm.wheel_common_rel_sigma = sc;
                        nm.wheel_common_time_constant_s = tau;
                        let o = EivOptions { noise: nm, fix_noise: true, ..base.clone() };
                        let p = estimate(&input, &gn, &o)?;
                        println!(
                            "    profile τ_c {tau} σ_c {sc:.4}: M {:.3} c_e {:+.4}% σ_H {:.4}",
                            p.final_cost,
                            ce(&p),
                            pct(p.sigma[0])
                        );
                    }
                }
            }
        }
    }
    println!("\nvariant | n | c_e mean % | sd | mean σ_H | σ_B | σ_F | coverage H / B / F");
    for (k, v) in &rows {
        let n = v.len() as f64;
        let m = v.iter().map(|x| x[0]).sum::<f64>() / n;
        let sd = (v.iter().map(|x| (x[0] - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
        let ms = |i: usize| v.iter().map(|x| x[i]).sum::<f64>() / n;
        let cov = |i: usize| v.iter().filter(|x| x[0].abs() <= 1.96 * x[i]).count() as f64 / n * 100.0;
        println!(
            "{k} | {} | {m:+.4} | {sd:.4} | {:.4} | {:.4} | {:.4} | {:.0} / {:.0} / {:.0} %",
            v.len(),
            ms(1),
            ms(2),
            ms(3),
            cov(1),
            cov(2),
            cov(3)
        );
    }
    Ok(())
}
