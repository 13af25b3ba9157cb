//! The heading-drift test's statistic towards more drift at the floor
//! (`upward_at_floor`, the guard tried and not kept) on random noise worlds
//! (docs/validation.md, "What is left: the drift's correlation time, and no
//! guard").
//!
//! World i (world seed `--seed` + i, i = 0..`--worlds`) is simulated as in
//! `random_worlds` (`NoiseOptions::random_world`, paper route, drive seed =
//! world seed, `--length-km` long) and calibrated with the default. Per
//! world: the reference's position and heading drift σ and correlation
//! times, the fit's η_4, the heading-drift test's statistic towards more
//! heading drift where the fit holds the heading drift at its floor
//! (`upward_at_floor`), t_r's error (%) and its z-score (error over the
//! result's σ), and the verdict with its reasons' kinds. Worlds run in
//! parallel (`--threads`); the output does not depend on it.

use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal::{calibrate, CalibrationOptions};
use odocal_lab::report_json::eiv_part;
use odocal_lab::{errors, Args, Res, Table};
use rayon::prelude::*;

const USAGE: &str = "rtk_guard_worlds [--worlds 30] [--length-km 12] [--seed 101] [--threads N]";

/// One world's row of the table.
fn world_row(seed: u64, km: f64) -> Res<Vec<String>> {
    let (noise, _) = NoiseOptions::random_world(seed);
    let sim = SimOptions { length_km: km, noise: noise.clone(), ..SimOptions::paper(seed) };
    let truth = sim.equivalent_truth().0;
    let out = simulate(&sim)?;
    let r = calibrate(&out.drive, &CalibrationOptions::default())?;
    let e = errors(&r.theta, &truth);
    let z = (r.theta.t_r - truth.t_r) / r.result_sigma().t_r.unwrap_or(f64::NAN);
    let part = eiv_part(&r);
    let eiv = part.as_ref().and_then(|p| p.eiv.as_ref());
    let eta_4 = eiv.map_or(f64::NAN, |e| e.eta[4]);
    let up = eiv.and_then(|e| e.heading_drift.as_ref()).and_then(|h| h.upward_at_floor);
    let kinds: Vec<String> = r
        .verdict
        .reasons
        .iter()
        .filter_map(|x| serde_json::to_value(x).ok()?.get("kind")?.as_str().map(str::to_string))
        .collect();
    Ok(vec![
        seed.to_string(),
        format!("{:.3} / {:.0}", noise.position_drift_sigma_m, noise.position_drift_time_constant_s),
        format!("{:.2} / {:.0}", noise.heading_drift_sigma_rad * 1e3, noise.heading_drift_time_constant_s),
        format!("{:.3}", noise.position_white_sigma_m),
        format!("{:.2}", noise.heading_white_sigma_rad * 1e3),
        format!("{eta_4:+.2}"),
        up.map_or("–".to_string(), |u| format!("{u:.1}")),
        format!("{:+.3}", e[2]),
        format!("{z:+.2}"),
        format!("{} {}", r.verdict.level, kinds.join(" ")),
    ])
}

fn main() {
    odocal_lab::main_with(|| {
        let mut a = Args::parse(USAGE, &[])?;
        let worlds: u64 = a.get("worlds", 30)?;
        let km: f64 = a.get("length-km", 12.0)?;
        let first: u64 = a.get("seed", 101)?;
        let threads: Option<usize> = a.opt("threads")?;
        a.finish()?;
        if let Some(n) = threads {
            rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
        }
        let rows: Vec<Vec<String>> = (first..first + worlds)
            .into_par_iter()
            .map(|seed| world_row(seed, km).map_err(|e| format!("world seed {seed}: {e}")))
            .collect::<Result<_, String>>()?;
        let mut t = Table::new(&[
            "world seed",
            "position drift m / τ s",
            "heading drift mrad / τ s",
            "position white m",
            "heading white mrad",
            "η_4",
            "upward at floor",
            "t_r error %",
            "t_r z",
            "verdict",
        ]);
        for r in rows {
            t.row(r);
        }
        println!("{t}");
        Ok(())
    });
}
