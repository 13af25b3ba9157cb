//! Coverage of batch Gauss-Newton's 95 % intervals: the model σ
//! (`σ̂²(JᵀWJ)⁻¹`, [`odocal::identify::IdentifyReport::covariance`]) against the
//! cluster-robust σ ([`odocal::identify::RobustCovariance`]), over simulated drives
//! with a known truth (docs/validation.md, "Coverage of the reported σ" and
//! "Reference extrinsics").
//!
//! Defaults: 20 seeds, 12 km, presets `off,white,paper,high`, cluster
//! lengths `1300` samples, FIT `theta,joint`. FIT `theta`: reference at the
//! rear-axle centre, θ estimated; `joint`: reference at l = (−0.9, 0.05) m,
//! δ = −9.9 mrad, θ and the extrinsics estimated; `three-step`: the
//! default 3-step calibration (its σ are step 3's). Each other fit is the batch-gn
//! method's: default selection (turning segments), default G-N options
//! (5 iterations), from θ_0 = [`Theta::PAPER_INITIAL`] and zero extrinsics.
//!
//! Per parameter it prints the fraction of seeds whose error lies within
//! 1.96 σ (model; robust) and within t_{G−1,0.975} robust σ, the RMS error
//! over seeds, the fraction within 3 robust σ, the mean error (bias) and
//! the standard deviation of the error over seeds, and the RMS of each σ. An honest σ
//! has RMS σ ≈ RMS error and coverage ≈ 95 %, unless the bias dominates.

use std::time::Instant;

use odocal::identify::{batch_gauss_newton, IdentifyOptions, IdentifyReport};
use odocal::segment::{calibration_segments, SegmentData};
use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal::{Extrinsics, ParamSet, Theta};
use odocal_lab::{t975, Args, Res, Summary};

const USAGE: &str = "gn_coverage [SEEDS 20] [KM 12] [PRESETS off,white,paper,high] [BLOCKS 1300] [FIT theta,joint]";

const MOUNT: Extrinsics = Extrinsics { lever_x: -0.9, lever_y: 0.05, heading_offset: -0.0099 };
const NAMES: [&str; 7] = ["c_e", "c_d", "t_r", "d", "lever_x", "lever_y", "heading_offset"];

/// Error, model σ, robust σ and cluster count of each estimated parameter.
struct Fit {
    err: Vec<f64>,
    model: Vec<f64>,
    robust: Vec<f64>,
    clusters: usize,
}

fn fit(r: &IdentifyReport, truth: &Theta, mount: &Extrinsics, joint: bool) -> Fit {
    let n = if joint { 7 } else { 4 };
    let rb = r.robust.as_ref();
    let mut f = Fit { err: vec![], model: vec![], robust: vec![], clusters: rb.map_or(0, |b| b.clusters) };
    for i in 0..n {
        let (est, want, sm, sr) = if i < 4 {
            (
                <[_; 4]>::from(r.theta)[i],
                <[_; 4]>::from(truth)[i],
                r.covariance[i][i].sqrt(),
                rb.map_or(f64::NAN, |b| b.covariance[i][i].sqrt()),
            )
        } else {
            let x = r.extrinsics.as_ref().expect("joint fit has extrinsics");
            (
                <[_; 3]>::from(x.value)[i - 4],
                <[_; 3]>::from(mount)[i - 4],
                <[_; 3]>::from(x.std_dev)[i - 4],
                x.robust.as_ref().map_or(f64::NAN, |b| <[_; 3]>::from(b.std_dev)[i - 4]),
            )
        };
        f.err.push(est - want);
        f.model.push(sm);
        f.robust.push(sr);
    }
    f
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    let seeds: u64 = args.pos(0, 20)?;
    let km: f64 = args.pos(1, 12.0)?;
    let presets: String = args.pos(2, "off,white,paper,high".to_string())?;
    let blocks: Vec<usize> = args.pos(3, "1300".to_string())?.split(',').map(str::parse).collect::<Result<_, _>>()?;
    let fits: String = args.pos(4, "theta,joint".to_string())?;
    args.finish()?;
    for preset in presets.split(',') {
        for kind in fits.split(',') {
            let joint = kind == "joint";
            let mount = if joint { MOUNT } else { Extrinsics::default() };
            let free = if joint { ParamSet::THETA.union(ParamSet::EXTRINSICS) } else { ParamSet::THETA };
            let mut per_block: Vec<Vec<Fit>> = blocks.iter().map(|_| Vec::new()).collect();
            let (mut t_fit, mut segs) = (0.0, 0usize);
            for seed in 1..=seeds {
                let sim = SimOptions {
                    length_km: km,
                    noise: preset.parse::<NoiseOptions>()?,
                    reference_mount: mount,
                    ..SimOptions::paper(seed)
                };
                let drive = simulate(&sim)?.drive;
                let sel = calibration_segments(&drive, &Default::default())?;
                let data: Vec<SegmentData> = sel.iter().map(|s| SegmentData::new(&drive, s)).collect();
                segs += data.len();
                if kind == "three-step" {
                    // The default 3-step calibration; its σ are step 3's.
                    for (b, block) in blocks.iter().enumerate() {
                        let mut o = odocal::CalibrationOptions::default();
                        o.identify.robust_block_steps = *block;
                        let t = Instant::now();
                        let r = odocal::calibrate(&drive, &o)?;
                        t_fit += t.elapsed().as_secs_f64();
                        let id = odocal_lab::report_json::identification(&r);
                        per_block[b].push(fit(&id, &sim.theta_true, &mount, false));
                    }
                    continue;
                }
                for (b, block) in blocks.iter().enumerate() {
                    let opts = IdentifyOptions { free, robust_block_steps: *block, ..Default::default() };
                    let t = Instant::now();
                    let r = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts)?;
                    t_fit += t.elapsed().as_secs_f64();
                    per_block[b].push(fit(&r, &sim.theta_true, &mount, joint));
                }
            }
            println!(
                "\n== preset {preset}, fit {kind}: {seeds} seeds x {km} km, mean {:.0} segments, mean fit {:.3} s",
                segs as f64 / seeds as f64,
                t_fit / (seeds as f64 * blocks.len() as f64)
            );
            for (b, block) in blocks.iter().enumerate() {
                let v = &per_block[b];
                let g = v.iter().map(|f| f.clusters as f64).sum::<f64>() / v.len() as f64;
                println!("-- cluster length {block} samples: mean G = {g:.1}");
                println!(
                    "param          | cover model | cover robust 1.96 | cover robust t(G-1) | within 3σ robust | RMS err   | mean err  | SD err    | RMS σ model | RMS σ robust | robust/model"
                );
                for (i, name) in NAMES.iter().enumerate().take(v[0].err.len()) {
                    let n = v.len() as f64;
                    let within =
                        |k: &dyn Fn(&Fit) -> f64| v.iter().filter(|f| f.err[i].abs() <= k(f)).count() as f64 / n;
                    let cm = within(&|f| 1.96 * f.model[i]);
                    let cr = within(&|f| 1.96 * f.robust[i]);
                    let ct = within(&|f| t975((f.clusters as f64 - 1.0).max(1.0)) * f.robust[i]);
                    let c3 = within(&|f| 3.0 * f.robust[i]);
                    let rms = |k: &dyn Fn(&Fit) -> f64| (v.iter().map(|f| k(f).powi(2)).sum::<f64>() / n).sqrt();
                    let (re, rm, rr) = (rms(&|f| f.err[i]), rms(&|f| f.model[i]), rms(&|f| f.robust[i]));
                    let s = Summary::of(&v.iter().map(|f| f.err[i]).collect::<Vec<_>>());
                    let (mean, sd) = (s.mean, s.sd);
                    println!(
                        "{:<14} | {:>11.2} | {:>17.2} | {:>19.2} | {c3:>16.2} | {re:>9.3e} | {mean:>+9.2e} | {sd:>9.3e} | {rm:>11.3e} | {rr:>12.3e} | {:>12.1}",
                        name,
                        cm,
                        cr,
                        ct,
                        rr / rm
                    );
                }
            }
        }
    }
    Ok(())
}
