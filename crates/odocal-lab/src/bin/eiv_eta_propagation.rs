//! How much of θ̂'s spread comes from the noise scales
//! η having been estimated from the same drive? For each simulated drive it
//! fits EIV with the default options (η estimated), then re-fits with the
//! noise model held at the fitted one with η_j moved by ±h, one source at a
//! time, to get the sensitivity s_j = ∂θ̂/∂η_j by central differences, and
//! reports the propagated variance Σ_j s_j² σ²(η̂_j) next to the reported σ.
//! Coverage of the truth by θ̂ ± 1.96 σ is printed for both. The library's
//! η term (`ResearchOptions::noise_estimate_term`, on by default)
//! computes the same by the implicit function theorem; the line
//! "library σ_η-term/σ_refit-term" compares the two.

use odocal::eiv::{estimate, EivInput, EivOptions, NoiseEstimateTerm, ResearchOptions};
use odocal_lab::{batch_gn_all, simulate_preset, Args, Res, PARAMETERS};

const USAGE: &str = "eiv_eta_propagation [--km 12] [--seeds 10] [--presets paper,high] [--h 0.05] [--refits 1]
    (presets also white, coloured; --refits 0: no re-fits, the η term alone)";

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &[])?;
    let km: f64 = a.get("km", 12.0)?;
    let seeds: u64 = a.get("seeds", 10)?;
    let presets = a.list("presets", &["paper", "high"]);
    let h: f64 = a.get("h", 0.05)?;
    let refits = a.get("refits", "1".to_string())? != "0";
    a.finish()?;
    let names = PARAMETERS;
    for p in &presets {
        // Per parameter: cover (reported), cover (with η propagated), Σ err², Σ σ², Σ σ_tot².
        let mut acc = [[0.0f64; 5]; 4];
        let mut n = 0usize;
        for seed in 1..=seeds {
            let sim = simulate_preset(p, km, seed)?;
            let d = &sim.drive;
            let truth = <[_; 4]>::from(sim.sidecar.theta_true);
            let gn = batch_gn_all(d)?;
            let input = EivInput::from_drive(d);
            // One fit with the default options. The σ without the η term is
            // the base: σ_old² = σ² − σ_η² (the option changes the covariance
            // only; the library test holds it to 1e-9).
            let r = estimate(&input, &gn, &EivOptions::default())?;
            let sigma_old: [f64; 4] = std::array::from_fn(|i| {
                (r.sigma[i] * r.sigma[i] - r.sigma_noise_estimate[i] * r.sigma_noise_estimate[i]).max(0.0).sqrt()
            });
            // The re-fits need only θ.
            let opts = EivOptions {
                research: ResearchOptions { noise_estimate_term: NoiseEstimateTerm::Omitted, ..Default::default() },
                ..EivOptions::default()
            };
            let th = <[_; 4]>::from(r.theta);
            let mut var_prop = [0.0f64; 4];
            let mut sens = Vec::new();
            for j in 0..6 {
                if r.eta_sigma[j] <= 0.0 || !refits {
                    continue;
                }
                let fit = |sign: f64| -> Res<[f64; 4]> {
                    let mut e = [0.0; 6];
                    e[j] = sign * h;
                    let o = EivOptions { noise: r.noise.scaled(&e), fix_noise: true, ..opts.clone() };
                    Ok(<[_; 4]>::from(estimate(&input, &r.theta, &o)?.theta))
                };
                let (a, b) = (fit(1.0)?, fit(-1.0)?);
                let s: [f64; 4] = std::array::from_fn(|i| (a[i] - b[i]) / (2.0 * h));
                for i in 0..4 {
                    var_prop[i] += (s[i] * r.eta_sigma[j]).powi(2);
                }
                sens.push(format!("η{j} σ {:.3} ∂t_r/∂η {:+.3}%", r.eta_sigma[j], s[2] / truth[2] * 100.0));
            }
            n += 1;
            eprintln!(
                "ERR {p} {seed} {} {} {}",
                (0..4).map(|i| format!("{:.6e}", th[i] - truth[i])).collect::<Vec<_>>().join(" "),
                (0..4).map(|i| format!("{:.6e}", r.sigma_noise_estimate[i])).collect::<Vec<_>>().join(" "),
                (0..4).map(|i| format!("{:.6e}", sigma_old[i])).collect::<Vec<_>>().join(" ")
            );
            let mut line = format!("{p} {seed}:");
            for i in 0..4 {
                let err = th[i] - truth[i];
                let s0 = sigma_old[i];
                let st = (s0 * s0 + var_prop[i]).sqrt();
                acc[i][0] += f64::from(u8::from(err.abs() <= 1.96 * s0));
                acc[i][1] += f64::from(u8::from(err.abs() <= 1.96 * st));
                acc[i][2] += err * err;
                acc[i][3] += s0 * s0;
                acc[i][4] += st * st;
                line += &format!(
                    " {} err/σ {:+.2} err/σ_tot {:+.2} (σ_tot/σ {:.2});",
                    names[i],
                    err / s0,
                    err / st,
                    st / s0
                );
            }
            line += &format!(
                " library σ_η-term/σ_refit-term t_r {:.2}, d {:.2}",
                r.sigma_noise_estimate[2] / var_prop[2].sqrt(),
                r.sigma_noise_estimate[3] / var_prop[3].sqrt()
            );
            println!("{line}\n    η̂ [{}] {}", r.eta.map(|e| format!("{e:+.3}")).join(" "), sens.join(", "));
        }
        let nf = n as f64;
        for i in 0..4 {
            println!(
                "{p} {}: coverage reported {:.0} %, with η propagated {:.0} %; RMS err / RMS σ {:.2}, / RMS σ_tot {:.2}",
                names[i],
                acc[i][0] / nf * 100.0,
                acc[i][1] / nf * 100.0,
                (acc[i][2] / acc[i][3]).sqrt(),
                (acc[i][2] / acc[i][4]).sqrt()
            );
        }
    }
    Ok(())
}
