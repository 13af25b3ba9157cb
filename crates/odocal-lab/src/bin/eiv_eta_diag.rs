//! Diagnostic of the EIV noise-scale (η) estimate: where do the scales go
//! from different starting noise models, and what does θ do?
//!
//! Presets: `paper`, `high`, `white`, `off`, `coloured`; `noslip`, `nobeta`,
//! `noquant`, `highnoquant`, `quantonly`, `quantwhite`, `white2`; the
//! quantisation-free paper ablations `nq-noslip`, `nq-noay`, `nq-nodrift`,
//! `nq-noposwhite`, `nq-nocoloured`, `nq-nowheel`; `high-A+B…` = high with
//! sources A, B… off (A one of noslip, noquant, paperq, noay, nobeta,
//! nodrift, noposwhite, noheadwhite, nocommon, nodiff, nowhite, paperwhite,
//! noref, nowheel); `scaleF` = every paper source × F.
//!
//! Variants (starting noise models): `known` (the simulator's, fixed),
//! `est-pc` (the production car's, estimated), `est-from-sim`, `est-pc-q`,
//! `est-pc-truth`, `est-from-sim-truth` (started at, and c_e alone free
//! from, θ_true), `est-pc-simtau`, `est-pc-head`, `est-pc-simtau-head`,
//! `est-pc-simwheel`, `est-pc-simdrift` (the simulator's time constants or
//! heading σ), and with the encoder's q given (`QuantisationLevel::Given`):
//! `est-pc-qgiven`, `est-from-sim-qgiven`, `est-pc-simtau-qgiven`,
//! `est-pc-simwheel-qgiven`, `est-pc-simdrift-qgiven`. Several quantisation
//! models (comma separated) run side by side on the same drives; the run
//! ends with a table of the mean θ error, its standard error and t =
//! mean/se over the seeds per preset, variant and model. `--heading`
//! defaults to `separate` here, as in the library; `--passes` applies with
//! the covariance held (`ResearchOptions::passes`).

use odocal::eiv::{
    estimate, EivInput, EivOptions, HeadingScale, NoiseModel, QuantisationLevel, QuantisationModel, ResearchOptions,
};
use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal::Theta;
use odocal_lab::{batch_gn_all, Args, Res};

const USAGE: &str = "eiv_eta_diag [--km 12] [--seeds 4] [--presets paper,high] [--variants known,est-pc,…]
    [--quantisation process,measurement,counting] [--heading separate|tied] [--substeps 10]
    [--window-samples N] [--hold 1,5] [--passes N] [--start truth] [--history]

--hold: η sources held at the starting model (EivOptions::eta_held); --start truth: start at θ_true;
--history: every iteration's θ, η and step/σ, and each window's NIS and lag-1";

/// (preset, variant, quantisation model), θ errors per seed, failed fits.
type SummaryRow = ((String, String, String), Vec<[f64; 4]>, usize);

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &["history"])?;
    let km: f64 = a.get("km", 12.0)?;
    let seeds: u64 = a.get("seeds", 4)?;
    let presets = a.list("presets", &["paper", "high"]);
    let variants_arg: Option<Vec<String>> =
        a.opt::<String>("variants")?.map(|v| v.split(',').map(str::to_string).collect());
    let mut quants = Vec::new();
    for name in a.list("quantisation", &["process"]) {
        let m: QuantisationModel = name.parse()?;
        quants.push((
            match m {
                QuantisationModel::ProcessNoise => "process",
                QuantisationModel::Measurement => "measurement",
                QuantisationModel::Counting => "counting",
            },
            m,
        ));
    }
    let heading: HeadingScale = a.get("heading", HeadingScale::Separate)?;
    let history = a.flag("history");
    let substeps: usize = a.get("substeps", SimOptions::paper(0).substeps)?;
    let window_samples: Option<usize> = a.opt("window-samples")?;
    let mut eta_held = [false; 6];
    for j in a.list("hold", &[]) {
        let j: usize = j.parse()?;
        *eta_held.get_mut(j).ok_or("--hold takes source indices 0..=5")? = true;
    }
    let passes: Option<usize> = a.opt("passes")?;
    let start_truth = a.get("start", String::new())? == "truth";
    a.finish()?;
    // (preset, variant, quantisation model) → θ errors per seed: c_e %, c_d mm, t_r %, d ×1e3.
    let mut summary: Vec<SummaryRow> = Vec::new();
    for p in &presets {
        let noise = match p.as_str() {
            "noslip" => NoiseOptions { wheel_slip_per_m_per_s2: 0.0, ..NoiseOptions::paper() },
            "nobeta" => NoiseOptions { wheel_slip_per_m_per_s2: 0.0, sideslip_sigma_rad: 0.0, ..NoiseOptions::paper() },
            "quantonly" => NoiseOptions { encoder_ticks_per_revolution: 256, ..NoiseOptions::off() },
            "quantwhite" => NoiseOptions { encoder_ticks_per_revolution: 256, .."white".parse::<NoiseOptions>()? },
            "white2" => NoiseOptions { wheel_white_rel_sigma: 0.02, .."white".parse::<NoiseOptions>()? },
            "coloured" => NoiseOptions::coloured_wheels_only(),
            "noquant" => NoiseOptions { encoder_ticks_per_revolution: 0, ..NoiseOptions::paper() },
            "highnoquant" => NoiseOptions { encoder_ticks_per_revolution: 0, ..NoiseOptions::high() },
            // Ablations of the paper preset without quantisation (`nq-…`: one more source off).
            "nq-noslip" => {
                NoiseOptions { encoder_ticks_per_revolution: 0, wheel_slip_per_m_per_s2: 0.0, ..NoiseOptions::paper() }
            }
            "nq-noay" => NoiseOptions {
                encoder_ticks_per_revolution: 0,
                lateral_acceleration_white_sigma_m_per_s2: 0.0,
                ..NoiseOptions::paper()
            },
            "nq-nodrift" => NoiseOptions {
                encoder_ticks_per_revolution: 0,
                position_drift_sigma_m: 0.0,
                heading_drift_sigma_rad: 0.0,
                ..NoiseOptions::paper()
            },
            "nq-noposwhite" => NoiseOptions {
                encoder_ticks_per_revolution: 0,
                position_white_sigma_m: 0.0,
                heading_white_sigma_rad: 0.0,
                ..NoiseOptions::paper()
            },
            "nq-nowheel" => NoiseOptions {
                encoder_ticks_per_revolution: 0,
                wheel_white_rel_sigma: 0.0,
                wheel_coloured_rel_sigma: 0.0,
                wheel_coloured_differential_rel_sigma: 0.0,
                wheel_slip_per_m_per_s2: 0.0,
                ..NoiseOptions::paper()
            },
            "nq-nocoloured" => NoiseOptions {
                encoder_ticks_per_revolution: 0,
                wheel_coloured_rel_sigma: 0.0,
                wheel_coloured_differential_rel_sigma: 0.0,
                wheel_slip_per_m_per_s2: 0.0,
                ..NoiseOptions::paper()
            },
            // `high-a+b+…`: the high preset with the named sources switched off, one
            // or more (see `ablate`); `scaleF`: every paper source × F (q by F too), F ∈ (0, 10].
            _ if p.starts_with("high-") => {
                let mut n = NoiseOptions::high();
                for a in p["high-".len()..].split('+') {
                    n = ablate(n, a)?;
                }
                n
            }
            _ if p.starts_with("scale") => NoiseOptions::paper_scaled(p["scale".len()..].parse()?),
            _ => p.parse::<NoiseOptions>()?,
        };
        for seed in 1..=seeds {
            let sim =
                simulate(&SimOptions { length_km: km, noise: noise.clone(), substeps, ..SimOptions::paper(seed) })?;
            let d = &sim.drive;
            let truth = sim.sidecar.theta_true;
            let gn = batch_gn_all(d)?;
            let input = EivInput::from_drive(d);
            let sim_noise = NoiseModel::from_sim(&noise, d.sample_time_s());
            let pc = NoiseModel::PRODUCTION_CAR;
            let pc_tau = NoiseModel {
                wheel_common_time_constant_s: sim_noise.wheel_common_time_constant_s,
                wheel_differential_time_constant_s: sim_noise.wheel_differential_time_constant_s,
                drift_time_constant_s: sim_noise.drift_time_constant_s,
                ..pc
            };
            let pc_head = NoiseModel { heading_white_sigma_rad: sim_noise.heading_white_sigma_rad, ..pc };
            let pc_tau_head = NoiseModel {
                heading_white_sigma_rad: sim_noise.heading_white_sigma_rad,
                wheel_differential_rel_sigma: sim_noise.wheel_differential_rel_sigma,
                ..pc_tau
            };
            // Only the wheel (τ_c, τ_w) or only the drift time constant from the simulator.
            let pc_simwheel = NoiseModel {
                wheel_common_time_constant_s: sim_noise.wheel_common_time_constant_s,
                wheel_differential_time_constant_s: sim_noise.wheel_differential_time_constant_s,
                ..pc
            };
            let pc_simdrift = NoiseModel { drift_time_constant_s: sim_noise.drift_time_constant_s, ..pc };
            let all = [
                // The encoder's q given (the simulator's ticks), not scaled by η_0.
                (
                    "est-pc-qgiven",
                    NoiseModel { quantisation_step_rev_per_s: sim_noise.quantisation_step_rev_per_s, ..pc },
                    false,
                ),
                ("est-from-sim-qgiven", sim_noise, false),
                // q given and the simulator's time constants (all, wheel only, drift only).
                (
                    "est-pc-simtau-qgiven",
                    NoiseModel { quantisation_step_rev_per_s: sim_noise.quantisation_step_rev_per_s, ..pc_tau },
                    false,
                ),
                (
                    "est-pc-simwheel-qgiven",
                    NoiseModel { quantisation_step_rev_per_s: sim_noise.quantisation_step_rev_per_s, ..pc_simwheel },
                    false,
                ),
                (
                    "est-pc-simdrift-qgiven",
                    NoiseModel { quantisation_step_rev_per_s: sim_noise.quantisation_step_rev_per_s, ..pc_simdrift },
                    false,
                ),
                ("est-pc-simwheel", pc_simwheel, false),
                ("est-pc-simdrift", pc_simdrift, false),
                ("est-pc-head", pc_head, false),
                ("est-pc-simtau-head", pc_tau_head, false),
                ("known", sim_noise, true),
                ("est-from-sim", sim_noise, false),
                ("est-pc", pc, false),
                (
                    "est-pc-q",
                    NoiseModel { quantisation_step_rev_per_s: sim_noise.quantisation_step_rev_per_s, ..pc },
                    false,
                ),
                ("est-pc-truth", pc, false),
                ("est-from-sim-truth", sim_noise, false),
                ("est-pc-simtau", pc_tau, false),
            ];
            let errs = |t: &Theta| {
                let (a, b) = (<[_; 4]>::from(t), <[_; 4]>::from(truth));
                [(a[0] - b[0]) / b[0] * 100.0, (a[1] - b[1]) * 1e3, (a[2] - b[2]) / b[2] * 100.0, (a[3] - b[3]) * 1e3]
            };
            let err = |t: &Theta| {
                let (a, b) = (<[_; 4]>::from(t), <[_; 4]>::from(truth));
                format!(
                    "c_e {:+.3}% c_d {:+.3}mm t_r {:+.2}% d {:+.3}",
                    (a[0] - b[0]) / b[0] * 100.0,
                    (a[1] - b[1]) * 1e3,
                    (a[2] - b[2]) / b[2] * 100.0,
                    (a[3] - b[3]) * 1e3
                )
            };
            println!("{p} {seed}: G-N {}", err(&gn));
            println!("      truth: {}", sim_noise);
            for ((label, nm, fix), &(qname, quant)) in
                all.iter().flat_map(|a| quants.iter().map(move |q| (a, q))).map(|(a, q)| (*a, q))
            {
                if let Some(v) = &variants_arg {
                    if !v.iter().any(|x| x == label) {
                        continue;
                    }
                }
                let key = (p.clone(), label.to_string(), qname.to_string());
                let idx = match summary.iter().position(|(k, _, _)| *k == key) {
                    Some(i) => i,
                    None => {
                        summary.push((key, Vec::new(), 0));
                        summary.len() - 1
                    }
                };
                let at_truth = label.ends_with("-truth");
                let free = if at_truth { [true, false, false, false] } else { [true; 4] };
                let opts = EivOptions {
                    noise: nm,
                    fix_noise: fix,
                    free,
                    quantisation: quant,
                    heading_scale: heading,
                    quantisation_level: if label.ends_with("-qgiven") {
                        QuantisationLevel::Given
                    } else {
                        QuantisationLevel::ScaledWithWhite
                    },
                    ..Default::default()
                };
                let research = ResearchOptions { passes: passes.unwrap_or(opts.research.passes), ..Default::default() };
                let opts = EivOptions {
                    window_samples: window_samples.unwrap_or(opts.window_samples),
                    eta_held,
                    research,
                    ..opts
                };
                let start = if at_truth || start_truth { truth } else { gn };
                match estimate(&input, &start, &opts) {
                    Ok(r) => {
                        summary[idx].1.push(errs(&r.theta));
                        let nis: Vec<f64> = r.windows.iter().map(|w| w.nis).collect();
                        let nis_m = nis.iter().sum::<f64>() / nis.len() as f64;
                        println!(
                            "  {label:14} {qname:11} {} | η [{}] M {:.1} it {} {} nis {:.2} {:.1}s",
                            err(&r.theta),
                            r.eta.iter().map(|e| format!("{e:+.2}")).collect::<Vec<_>>().join(" "),
                            r.final_cost,
                            r.iterations,
                            r.termination,
                            nis_m,
                            r.timing_s
                        );
                        println!("      noise: {}", r.noise);
                        for w in &r.warnings {
                            println!("      warning: {w}");
                        }
                        if history {
                            for (i, h) in r.passes.iter().flat_map(|p| p.history.iter()).enumerate() {
                                println!(
                                    "      it {i}: {} | η [{}] cost {:.3} step/σ {:.3e} λ {}",
                                    err(&h.theta),
                                    h.eta.iter().map(|e| format!("{e:+.2}")).collect::<Vec<_>>().join(" "),
                                    h.cost,
                                    h.step_over_sigma,
                                    h.step_factor
                                );
                            }
                            for w in &r.windows {
                                println!(
                                    "      window {}: updates {} nis {:.3} (no floors {:.3}) lag1 [{:.3} {:.3} {:.3}] \
                                     (no floors [{:.3} {:.3} {:.3}])",
                                    w.window.index,
                                    w.updates,
                                    w.nis,
                                    w.nis_without_floors,
                                    w.lag1[0],
                                    w.lag1[1],
                                    w.lag1[2],
                                    w.lag1_without_floors[0],
                                    w.lag1_without_floors[1],
                                    w.lag1_without_floors[2]
                                );
                            }
                        }
                    }
                    Err(e) => {
                        summary[idx].2 += 1;
                        println!("  {label} {qname}: failed {e}")
                    }
                }
            }
        }
    }
    println!("\nmean ± se (t = mean/se) over seeds; c_e %, c_d mm, t_r %, d ×1e3");
    println!("preset | variant | quantisation | n (failed) | c_e | c_d | t_r | d");
    for ((p, label, q), e, failed) in &summary {
        let n = e.len() as f64;
        let cells: Vec<String> = (0..4)
            .map(|i| {
                let m = e.iter().map(|x| x[i]).sum::<f64>() / n;
                let var = e.iter().map(|x| (x[i] - m) * (x[i] - m)).sum::<f64>() / (n - 1.0).max(1.0);
                let se = (var / n).sqrt();
                format!("{m:+.3} ± {se:.3} (t {:+.1})", m / se)
            })
            .collect();
        println!("{p} | {label} | {q} | {} ({failed}) | {}", e.len(), cells.join(" | "));
    }
    Ok(())
}

/// The noise options with one source switched off (ablations of `high`).
fn ablate(n: NoiseOptions, what: &str) -> Res<NoiseOptions> {
    Ok(match what {
        "noslip" => NoiseOptions { wheel_slip_per_m_per_s2: 0.0, ..n },
        "noquant" => NoiseOptions { encoder_ticks_per_revolution: 0, ..n },
        "paperq" => {
            NoiseOptions { encoder_ticks_per_revolution: NoiseOptions::paper().encoder_ticks_per_revolution, ..n }
        }
        "noay" => NoiseOptions { lateral_acceleration_white_sigma_m_per_s2: 0.0, ..n },
        "nobeta" => NoiseOptions { sideslip_sigma_rad: 0.0, ..n },
        "nodrift" => NoiseOptions { position_drift_sigma_m: 0.0, heading_drift_sigma_rad: 0.0, ..n },
        "noposwhite" => NoiseOptions { position_white_sigma_m: 0.0, ..n },
        "noheadwhite" => NoiseOptions { heading_white_sigma_rad: 0.0, ..n },
        "nocommon" => NoiseOptions { wheel_coloured_rel_sigma: 0.0, ..n },
        "nodiff" => NoiseOptions { wheel_coloured_differential_rel_sigma: 0.0, ..n },
        "nowhite" => NoiseOptions { wheel_white_rel_sigma: 0.0, ..n },
        "paperwhite" => NoiseOptions { wheel_white_rel_sigma: NoiseOptions::paper().wheel_white_rel_sigma, ..n },
        "noref" => NoiseOptions {
            position_drift_sigma_m: 0.0,
            heading_drift_sigma_rad: 0.0,
            position_white_sigma_m: 0.0,
            heading_white_sigma_rad: 0.0,
            ..n
        },
        "nowheel" => NoiseOptions {
            wheel_slip_per_m_per_s2: 0.0,
            wheel_coloured_rel_sigma: 0.0,
            wheel_coloured_differential_rel_sigma: 0.0,
            wheel_white_rel_sigma: 0.0,
            encoder_ticks_per_revolution: 0,
            ..n
        },
        other => return Err(format!("unknown ablation '{other}'").into()),
    })
}
