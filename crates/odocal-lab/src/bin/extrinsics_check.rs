//! Reference-sensor extrinsics (lever arm, heading offset) measured: with
//! and without estimating them, on simulated drives with a known mount, on
//! the PSU van's highway log and on its six test-track runs
//! (docs/validation.md, "Reference extrinsics").
//!
//! METHOD is `batch-gn` (all segments: `--min-yaw-rate 0` on the van, the
//! default selection on the track) or `three-step` (default settings).
//! - `sim`: paper noise, reference at l = (−0.9, 0.05) m, δ = −9.9 mrad;
//!   batch G-N over θ and the extrinsics on each seed; error over σ.
//! - `van`: `examples/psu-mapping-van/manifest.toml`, whole drive and both
//!   half-splits (`--holdout`), without and with `--estimate
//!   lever-arm,heading-offset`: Ē_p, extrinsics ± σ, verdict.
//! - `track`: `examples/psu-mapping-van-testtrack/run-*.toml`; each run
//!   fitted and validated on the other five (as `--validate-on`), without
//!   and with extrinsics (HELD: parameters held at θ_0, e.g. `d`); c_d per
//!   direction over the runs not rejected (runs 14-45-26, 15-28-33,
//!   16-06-28 counter-clockwise, the others clockwise).
//!
//! Measured (batch-gn):
//! - sim, 6 km, seeds 1–5: noise off (10 substeps) errors ≤ 0.1 mm; white
//!   reference noise only ≤ 4 mm and 0.06 mrad; paper noise |l_x| errors
//!   0.02–0.96 m and δ 0.2–6.4 mrad, 20–55 model σ (the G-N σ assumes white
//!   residuals; the wheel/sideslip noise, not the reference's, moves them).
//!   The cluster-robust σ (printed beside it; needs ≥ 10 clusters, about
//!   6 km or more of turning drive) covers them: on 12 km, seeds 1–20, every
//!   extrinsics error lies within 3 robust σ (`gn_coverage 20 12 paper 1300 joint`).
//! - van, `--min-yaw-rate 0`: Ē_p whole 22.38 → 20.86 m, held-out first half
//!   24.51 → 24.20 m, second half 26.42 → 23.91 m with extrinsics, but the
//!   estimates (l_x −2.8, −0.2, −6.0 m; δ +25 to +37 mrad) disagree with each
//!   other and with the mount (−0.9 m, −9.9 mrad): not identifiable there.
//! - track, d held: mean cross-run Ē_p 7.16 m without, 7.59 m with; c_d
//!   clockwise minus counter-clockwise +1.7 mm without, +2.3 mm with; δ ≈
//!   +23 mrad on counter-clockwise runs, +7 to +10 mrad on clockwise ones.

use odocal::research::mean_position_error_with;
use odocal::segment::validation_segments;
use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal::{CalibrationOptions, CalibrationReport, Drive, Extrinsics, Holdout, Method, ParamSet, Theta};
use odocal_lab::{load, testtrack_runs, Args, Res, TESTTRACK_RUNS, VAN_MANIFEST};

const USAGE: &str = "extrinsics_check sim [SEEDS 5] [KM 8] [NOISE paper]
extrinsics_check van [METHOD batch-gn]
extrinsics_check track [METHOD batch-gn] [HELD]

NOISE: paper, off, reference, no-reference, white-reference, reference-white-only";

const MOUNT: Extrinsics = Extrinsics { lever_x: -0.9, lever_y: 0.05, heading_offset: -0.0099 };

fn options(method: &str, with_extrinsics: bool, all_segments: bool) -> Result<CalibrationOptions, odocal::Error> {
    let mut o = CalibrationOptions { method: method.parse::<Method>()?, ..Default::default() };
    if all_segments {
        o.segments.min_peak_yaw_rate_rad_per_s = 0.0;
    }
    if with_extrinsics {
        o.identify.free = o.identify.free.union(ParamSet::EXTRINSICS);
    }
    Ok(o)
}

fn extrinsics_cell(r: &CalibrationReport) -> String {
    match &r.extrinsics {
        Some(x) => format!(
            "l_x {:+.3}±{:.3} m, l_y {:+.3}±{:.3} m, δ {:+.2}±{:.2} mrad{}",
            x.value.lever_x,
            x.std_dev.lever_x,
            x.value.lever_y,
            x.std_dev.lever_y,
            x.value.heading_offset * 1e3,
            x.std_dev.heading_offset * 1e3,
            match &x.robust {
                Some(b) => format!(
                    " (robust σ {:.3} m, {:.3} m, {:.2} mrad)",
                    b.std_dev.lever_x,
                    b.std_dev.lever_y,
                    b.std_dev.heading_offset * 1e3
                ),
                None => String::new(),
            }
        ),
        None => "-".into(),
    }
}

/// The paper noise, or a part of it: `paper`, `reference` (reference-pose
/// noise only), `no-reference` (every source but the reference pose's),
/// `white-reference` (paper noise with the reference drifts off),
/// `reference-white-only` (only the reference's white noise: the noise the
/// model σ assumes).
fn noise(preset: &str) -> Result<NoiseOptions, odocal::Error> {
    let p = NoiseOptions::paper();
    let off = NoiseOptions::off();
    Ok(match preset {
        "paper" => p,
        "off" => off,
        "reference" => NoiseOptions {
            position_drift_sigma_m: p.position_drift_sigma_m,
            position_white_sigma_m: p.position_white_sigma_m,
            heading_drift_sigma_rad: p.heading_drift_sigma_rad,
            heading_white_sigma_rad: p.heading_white_sigma_rad,
            ..off
        },
        "no-reference" => NoiseOptions {
            position_drift_sigma_m: 0.0,
            position_white_sigma_m: 0.0,
            heading_drift_sigma_rad: 0.0,
            heading_white_sigma_rad: 0.0,
            ..p
        },
        "white-reference" => NoiseOptions { position_drift_sigma_m: 0.0, heading_drift_sigma_rad: 0.0, ..p },
        "reference-white-only" => NoiseOptions {
            position_white_sigma_m: p.position_white_sigma_m,
            heading_white_sigma_rad: p.heading_white_sigma_rad,
            ..off
        },
        other => {
            return Err(odocal::Error::InvalidOption {
                field: "noise",
                reason: format!("'{other}': paper, reference, no-reference, white-reference or reference-white-only"),
            })
        }
    })
}

fn sim(seeds: u64, km: f64, preset: &str) -> Result<(), odocal::Error> {
    println!("noise '{preset}', {km} km, reference mount {MOUNT}; batch G-N over θ and the extrinsics");
    println!(
        "seed | l_x err (model σ; robust σ) m | l_y err (model σ; robust σ) m | δ err (model σ; robust σ) mrad | |err|/σ max model; robust | c_e rel err | t_r rel err"
    );
    let (mut worst, mut worst_robust) = (0.0f64, 0.0f64);
    for seed in 1..=seeds {
        let drive = simulate(&SimOptions {
            length_km: km,
            reference_mount: MOUNT,
            noise: noise(preset)?,
            ..SimOptions::paper(seed)
        })?
        .drive;
        let r = odocal::calibrate(&drive, &options("batch-gn", true, false)?)?;
        let x = r.extrinsics.as_ref().ok_or_else(|| odocal::Error::Numerical("no extrinsics".into()))?;
        let err: Vec<f64> = <[_; 3]>::from(x.value).iter().zip(<[_; 3]>::from(MOUNT)).map(|(a, b)| a - b).collect();
        let sd = <[_; 3]>::from(x.std_dev);
        // The cluster-robust σ (NaN when the drive gives too few clusters).
        let rs = x.robust.as_ref().map_or([f64::NAN; 3], |b| <[_; 3]>::from(b.std_dev));
        let z = (0..3).map(|i| (err[i] / sd[i]).abs()).fold(0.0, f64::max);
        let zr = (0..3).map(|i| (err[i] / rs[i]).abs()).fold(0.0, f64::max);
        worst = worst.max(z);
        worst_robust = worst_robust.max(zr);
        let t = Theta::SIM_DEFAULT_TRUE;
        let cell = |i: usize, s: f64| format!("{:+.4} ({:.4}; {:.4})", err[i] * s, sd[i] * s, rs[i] * s);
        println!(
            "{seed} | {} | {} | {} | {z:.2}; {zr:.2} | {:+.4} % | {:+.3} %",
            cell(0, 1.0),
            cell(1, 1.0),
            cell(2, 1e3),
            (r.theta.c_e / t.c_e - 1.0) * 100.0,
            (r.theta.t_r / t.t_r - 1.0) * 100.0
        );
    }
    println!("largest |error|/σ over seeds and extrinsics: model σ {worst:.2}, robust σ {worst_robust:.2}");
    Ok(())
}

fn van(method: &str) -> Res<()> {
    let drive = load(VAN_MANIFEST)?;
    let all = method == "batch-gn";
    println!("PSU van, method {method}{}", if all { " --min-yaw-rate 0" } else { "" });
    println!("data | extrinsics | Ē_p θ_0 m | Ē_p m | c_d mm | t_r m | extrinsics ± σ | verdict");
    for (name, h) in [
        ("whole", None),
        ("held-out first half", Some(Holdout::FirstHalf)),
        ("held-out second half", Some(Holdout::SecondHalf)),
    ] {
        for with in [false, true] {
            let o = options(method, with, all)?;
            let r = match &h {
                None => odocal::calibrate(&drive, &o),
                Some(h) => odocal::Calibration { holdout: Some(h), ..odocal::Calibration::new(&drive, &o) }.run(),
            };
            match r {
                Ok(r) => println!(
                    "{name} | {} | {:.3} | {:.3} | {:+.3} | {:.4} | {} | {}",
                    if with { "estimated" } else { "none" },
                    r.initial.mean_position_error_m,
                    r.validation.mean_position_error_m,
                    r.theta.c_d * 1e3,
                    r.theta.t_r,
                    extrinsics_cell(&r),
                    r.verdict.level
                ),
                Err(e) => println!("{name} | {} | error: {e}", if with { "estimated" } else { "none" }),
            }
        }
    }
    Ok(())
}

fn cross_error(drive: &Drive, theta: &Theta, e: &Extrinsics) -> Result<f64, odocal::Error> {
    let segs = validation_segments(drive, &Default::default())?;
    Ok(mean_position_error_with(drive, &segs, theta, e)?.mean_position_error_m)
}

fn track(method: &str, fix: ParamSet) -> Res<()> {
    let drives: Vec<Drive> = testtrack_runs()?.into_iter().map(|(_, d)| d).collect();
    println!("test track, method {method} (default selection), held: [{fix}]; Ē_p on the other five runs");
    println!("run | dir | extrinsics | own Ē_p m | others Ē_p m (θ_0 m) | c_e m | c_d mm | t_r m | d mm/(m/s²) | extrinsics ± σ | verdict");
    for with in [false, true] {
        let mut cd = (Vec::new(), Vec::new());
        let mut cross = Vec::new();
        for (i, (run, dir)) in TESTTRACK_RUNS.iter().enumerate() {
            let mut o = options(method, with, false)?;
            o.identify.free = o.identify.free.difference(fix);
            let r = match odocal::calibrate(&drives[i], &o) {
                Ok(r) => r,
                Err(e) => {
                    println!("{run} | {dir} | error: {e}");
                    continue;
                }
            };
            let ext = r.extrinsics.as_ref().map_or(Extrinsics::default(), |x| x.value);
            let (mut sum, mut sum0) = (0.0, 0.0);
            for d in drives.iter().enumerate().filter(|(j, _)| *j != i).map(|(_, d)| d) {
                sum += cross_error(d, &r.theta, &ext)?;
                sum0 += cross_error(d, &o.theta0, &Extrinsics::default())?;
            }
            let others = sum / 5.0;
            cross.push(others);
            if *dir == "cw" {
                cd.0.push(r.theta.c_d)
            } else {
                cd.1.push(r.theta.c_d)
            }
            println!(
                "{run} | {dir} | {} | {:.3} | {others:.3} ({:.3}) | {:.5} | {:+.3} | {:.4} | {:+.3} | {} | {}",
                if with { "estimated" } else { "none" },
                r.validation.mean_position_error_m,
                sum0 / 5.0,
                r.theta.c_e,
                r.theta.c_d * 1e3,
                r.theta.t_r,
                r.theta.d * 1e3,
                extrinsics_cell(&r),
                r.verdict.level
            );
        }
        let mean = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len().max(1) as f64;
        println!(
            "extrinsics {}: mean cross-run Ē_p {:.3} m; mean c_d (runs not rejected) clockwise {:+.3} mm, counter-clockwise {:+.3} mm, difference {:+.3} mm",
            if with { "estimated" } else { "none" },
            mean(&cross),
            mean(&cd.0) * 1e3,
            mean(&cd.1) * 1e3,
            (mean(&cd.0) - mean(&cd.1)) * 1e3
        );
    }
    Ok(())
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    let what: String = args.pos(0, "sim".to_string())?;
    match what.as_str() {
        "sim" => sim(args.pos(1, 5)?, args.pos(2, 8.0)?, &args.pos(3, "paper".to_string())?)?,
        "van" => van(&args.pos(1, "batch-gn".to_string())?)?,
        "track" => track(&args.pos(1, "batch-gn".to_string())?, args.pos(2, ParamSet::default())?)?,
        other => return Err(format!("unknown part '{other}'\n\n{USAGE}").into()),
    }
    args.finish()
}
