//! EIV against batch Gauss-Newton (all segments) and the Cramér–Rao bound
//! on simulated drives: `cargo run --release -p odocal --example eiv_check [km] [seeds]`.

use std::time::Instant;

use odocal::eiv::{cramer_rao_bound, estimate, EivInput, EivOptions, NoiseModel};
use odocal::identify::{batch_gauss_newton, IdentifyOptions};
use odocal::segment::{calibration_segments, SegmentData, SegmentOptions};
use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal::{Drive, Theta};

/// The one place that reads a Drive's columns.
fn input_of(d: &Drive) -> EivInput<'_> {
    EivInput {
        sample_time_s: d.sample_time_s,
        parts: &d.parts,
        px: &d.px,
        py: &d.py,
        psi: &d.psi,
        n_rl: &d.n_rl,
        n_rr: &d.n_rr,
        beta: &d.beta,
        a_y: &d.a_y,
        reference_measured: None,
    }
}

fn main() -> Result<(), odocal::Error> {
    let args: Vec<String> = std::env::args().collect();
    let km: f64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(12.0);
    let seeds: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(3);
    println!("preset seed | err G-N [c_e %, c_d mm, t_r %, d mm/(m/s²)] | err EIV | EIV σ | CRB σ | EIV s | G-N s | warnings");
    for preset in ["off", "white", "paper", "high"] {
        for seed in 1..=seeds {
            let noise = NoiseOptions::by_name(preset)?;
            let out = simulate(&SimOptions { length_km: km, noise: noise.clone(), ..SimOptions::paper(seed) })?;
            let d = &out.drive;
            let truth = out.sidecar.theta_true;
            let t = Instant::now();
            let sel = calibration_segments(d, &SegmentOptions::default())?;
            let data: Vec<SegmentData> = sel.all.iter().map(|s| SegmentData::new(d, s)).collect();
            let gn = batch_gauss_newton(
                &data,
                &Theta::PAPER_INITIAL,
                &IdentifyOptions { max_iterations: 20, ..Default::default() },
            )?
            .theta;
            let t_gn = t.elapsed().as_secs_f64();
            let input = input_of(d);
            let r = estimate(&input, &gn, &EivOptions::default())?;
            let true_noise = NoiseModel::from_sim(&noise, d.sample_time_s);
            let crb = cramer_rao_bound(&input, &truth, &true_noise, &EivOptions::default()).ok();
            let scale = [100.0 / truth.c_e, 1e3, 100.0 / truth.t_r, 1e3];
            let err = |th: &Theta| -> Vec<String> {
                let (a, b) = (th.to_array(), truth.to_array());
                (0..4).map(|i| format!("{:+.3}", (a[i] - b[i]) * scale[i])).collect()
            };
            let sig = |s: &[f64; 4]| -> Vec<String> { (0..4).map(|i| format!("{:.3}", s[i] * scale[i])).collect() };
            println!(
                "{preset:5} {seed} | {} | {} | {} | {} | {:.2} | {:.2} | {} ({})",
                err(&gn).join(" "),
                err(&r.theta).join(" "),
                sig(&r.sigma).join(" "),
                crb.map(|c| sig(&c.sigma).join(" ")).unwrap_or_else(|| "singular".into()),
                r.timing_s,
                t_gn,
                r.warnings.len(),
                r.termination
            );
        }
    }
    // Speed: one 24 km paper drive.
    let out = simulate(&SimOptions { length_km: 24.0, ..SimOptions::paper(1) })?;
    let d = &out.drive;
    let r = estimate(&input_of(d), &out.sidecar.theta_true, &EivOptions::default())?;
    let r2 = estimate(&input_of(d), &out.sidecar.theta_true, &EivOptions { fix_noise: true, ..Default::default() })?;
    println!(
        "24 km ({} samples): EIV {:.2} s ({} iterations), with fix_noise {:.2} s ({} iterations)",
        d.len(),
        r.timing_s,
        r.iterations,
        r2.timing_s,
        r2.iterations
    );
    Ok(())
}
