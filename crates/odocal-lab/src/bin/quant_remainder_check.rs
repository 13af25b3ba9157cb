//! Is the encoder's counting error an MA(1) input error with independent
//! remainders, as [`odocal::eiv::QuantisationModel::Counting`] assumes?
//!
//! On a simulated drive with white relative wheel noise and quantisation
//! only (the preset's sizes), `d_k = ñ_k − n_k` (measured minus true rate)
//! is the white relative error plus the counting error `q(u_{k−1} − u_k)`.
//! With independent uniform remainders its autocovariance is `−q²/12` at
//! lag 1 and 0 beyond; the white part adds to lag 0 only. Printed per wheel
//! speed band (ticks counted per sample): the lag-1, lag-2 and lag-3
//! autocovariances in units of q²/12, and the samples where the wheel
//! counts nothing.

use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal_lab::{Args, Res};

const USAGE: &str = "quant_remainder_check [--km 12] [--seeds 4] [--presets paper,high]";

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &[])?;
    let km: f64 = a.get("km", 12.0)?;
    let seeds: u64 = a.get("seeds", 4)?;
    let presets = a.list("presets", &["paper", "high"]);
    a.finish()?;
    // Bands of ticks counted per sample (measured).
    let bands = [(0.0, 0.5), (0.5, 4.0), (4.0, 32.0), (32.0, f64::INFINITY)];
    for p in &presets {
        let full = p.parse::<NoiseOptions>()?;
        let noise = NoiseOptions {
            wheel_white_rel_sigma: full.wheel_white_rel_sigma,
            encoder_ticks_per_revolution: full.encoder_ticks_per_revolution,
            ..NoiseOptions::off()
        };
        let ticks = f64::from(noise.encoder_ticks_per_revolution);
        if ticks <= 0.0 {
            println!("{p}: no quantisation");
            continue;
        }
        // Per band: [Σ d_k d_{k−1}, Σ d_k d_{k−2}, Σ d_k d_{k−3}, samples].
        let mut acc = vec![[0.0f64; 4]; bands.len()];
        for seed in 1..=seeds {
            let sim = simulate(&SimOptions { length_km: km, noise: noise.clone(), ..SimOptions::paper(seed) })?;
            let d = &sim.drive;
            let ts = d.sample_time_s();
            let truth = d.truth().ok_or("no truth")?;
            let q = 1.0 / (ticks * ts);
            for (meas, tru) in [(&d.measured().n_rl, &truth.n_rl), (&d.measured().n_rr, &truth.n_rr)] {
                let e: Vec<f64> = meas.iter().zip(tru.iter()).map(|(m, t)| (m - t) / q).collect();
                for k in 3..e.len() {
                    let counted = meas[k].abs() / q;
                    let Some(b) = bands.iter().position(|(lo, hi)| counted >= *lo && counted < *hi) else {
                        continue;
                    };
                    let a = &mut acc[b];
                    a[0] += e[k] * e[k - 1];
                    a[1] += e[k] * e[k - 2];
                    a[2] += e[k] * e[k - 3];
                    a[3] += 1.0;
                }
            }
        }
        println!("{p} ({ticks} ticks/rev, {seeds} seeds × {km} km, both wheels): autocovariance of ñ − n in q²/12");
        println!("  ticks/sample | samples | lag 1 (−1 if independent) | lag 2 (0) | lag 3 (0)");
        for ((lo, hi), a) in bands.iter().zip(&acc) {
            let n = a[3].max(1.0);
            println!(
                "  [{lo}, {hi}) | {} | {:+.3} | {:+.3} | {:+.3}",
                a[3],
                a[0] / n * 12.0,
                a[1] / n * 12.0,
                a[2] / n * 12.0
            );
        }
    }
    Ok(())
}
