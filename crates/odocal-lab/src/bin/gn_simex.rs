//! The verdict's check of batch Gauss-Newton's errors-in-variables bias
//! (`input_noise_bias`, odocal's `calibrate::input_noise`) on simulated
//! drives with a known truth (docs/validation.md, "Batch Gauss-Newton's
//! input-noise bias").
//!
//! Per preset, over seeds 1..=SEEDS of KM km: `odocal calibrate --method
//! batch-gn` as a user runs it; per parameter the mean error over the σ
//! for the next drive against the mean predicted bias over that σ (the
//! check's `wheel_white_noise` and `simex_bias` at the result), the white
//! wheel noise estimated against the simulated, and how many results the
//! check makes doubtful and how many stay accepted beyond 3σ.
//!
//! `gn_simex [SEEDS 20] [KM 12] [PRESETS paper,white,coloured,high]`;
//! `gn_simex real`: the repository's real drives (`--method batch-gn
//! --estimate heading-offset`), the estimated wheel noise and the
//! predicted bias over the σ for the next drive;
//! `gn_simex worlds [FIRST 1] [N 100] [KM 12]`: random noise worlds (as
//! `random_worlds` drives them), the coverage of the reported 95 %
//! interval, the results accepted beyond 3σ, and per world beyond 3σ its
//! error and predicted bias over σ (docs/validation.md, "Batch Gauss-Newton's σ:
//! the jackknife over clusters").

use odocal::identify::IdentifyOptions;
use odocal::research::{calibrate_detailed, simex_bias, wheel_white_noise};
use odocal::segment::SegmentData;
use odocal::{CalibrationOptions, Method, VerdictLevel, VerdictReason};
use odocal_lab::{simulate_preset, Args, Res, Summary, Table};

const USAGE: &str =
    "gn_simex [SEEDS 20] [KM 12] [PRESETS paper,white,coloured,high] | gn_simex real | gn_simex worlds [FIRST 1] [N 100] [KM 12]";

const NAMES: [&str; 4] = ["c_e", "c_d", "t_r", "d"];

/// The real drives of the repository.
const REAL: [&str; 8] = [
    "examples/psu-mapping-van/manifest.toml",
    "examples/psu-mapping-van-testtrack/run-14-45-26.toml",
    "examples/psu-mapping-van-testtrack/run-15-28-33.toml",
    "examples/psu-mapping-van-testtrack/run-16-06-28.toml",
    "examples/psu-mapping-van-testtrack/run-16-47-33.toml",
    "examples/psu-mapping-van-testtrack/run-17-45-46.toml",
    "examples/psu-mapping-van-testtrack/run-18-01-26.toml",
    "examples/comma2k19-rav4/manifest.toml",
];

fn real() -> Res<()> {
    let mut o = CalibrationOptions { method: Method::BatchGn, ..Default::default() };
    o.identify.free = o.identify.free.with(odocal::Param::HeadingOffset);
    let mut table = Table::new(&["drive", "σ_w", "predicted bias / σ: c_e", "c_d", "t_r", "d", "verdict"]);
    for path in REAL {
        let drive = odocal_lab::load(path)?;
        let detailed = match calibrate_detailed(&drive, None, &o, None) {
            Ok(r) => r,
            Err(e) => {
                table.row([
                    path.to_string(),
                    format!("{e}"),
                    String::new(),
                    String::new(),
                    String::new(),
                    String::new(),
                    String::new(),
                ]);
                continue;
            }
        };
        let r = &detailed.report;
        let sigma: [Option<f64>; 4] = r.result_sigma().into();
        let data: Vec<SegmentData> = detailed.selected.iter().map(|s| SegmentData::new(&drive, s)).collect();
        let est = wheel_white_noise(&data, &r.theta);
        let mut io = o.identify.clone();
        if let Some(x) = &r.extrinsics {
            io.extrinsics = x.value;
        }
        let bias = est.and_then(|s| simex_bias(&data, drive.drive_starts(), &r.theta, &io, s, o.seed));
        let cell = |i: usize| match (bias, sigma[i]) {
            (Some(b), Some(s)) => format!("{:+.2}", b[i] / s),
            _ => "–".into(),
        };
        table.row([
            path.to_string(),
            est.map_or("none".into(), |s| format!("{:.3} %", s * 100.0)),
            cell(0),
            cell(1),
            cell(2),
            cell(3),
            format!("{}", r.verdict.level),
        ]);
    }
    print!("{table}");
    Ok(())
}

/// Random noise worlds FIRST..FIRST+N (`random_worlds`' drives): per world
/// whose batch G-N result (`--estimate heading-offset`) is accepted with
/// some parameter beyond 3σ of the equivalent truth, its error and the
/// predicted bias over σ, and the estimated against the simulated σ_w.
fn worlds(first: u64, n: u64, km: f64) -> Res<()> {
    use odocal::sim::{simulate, NoiseOptions, SimOptions};
    let mut o = CalibrationOptions { method: Method::BatchGn, ..Default::default() };
    o.identify.free = o.identify.free.with(odocal::Param::HeadingOffset);
    let mut table = Table::new(&["world", "regime", "σ_w est / sim", "error / σ", "predicted / σ", "verdict"]);
    let (mut worlds, mut covered, mut accepted_beyond, mut width) = (0usize, [0usize; 4], 0usize, vec![Vec::new(); 4]);
    for seed in first..first + n {
        let (noise, summary) = NoiseOptions::random_world(seed);
        let sim = SimOptions { length_km: km, noise: noise.clone(), ..SimOptions::paper(seed) };
        let drive = simulate(&sim)?.drive;
        let (truth, _) = sim.equivalent_truth();
        let detailed = calibrate_detailed(&drive, None, &o, None)?;
        let r = &detailed.report;
        let sigma: [Option<f64>; 4] = r.result_sigma().into();
        let s = sigma.map(|s| s.unwrap_or(f64::NAN));
        let (theta, truth) = (<[f64; 4]>::from(r.theta), <[f64; 4]>::from(truth));
        let err: [f64; 4] = std::array::from_fn(|i| (theta[i] - truth[i]) / s[i]);
        worlds += 1;
        for i in 0..4 {
            covered[i] += usize::from(err[i].abs() <= 1.96);
            width[i].push(s[i].ln());
        }
        let beyond = err.iter().any(|e| e.abs() > 3.0);
        accepted_beyond += usize::from(beyond && r.verdict.level == VerdictLevel::Accepted);
        if !beyond {
            continue;
        }
        let data: Vec<SegmentData> = detailed.selected.iter().map(|x| SegmentData::new(&drive, x)).collect();
        let est = wheel_white_noise(&data, &r.theta);
        let mut io = o.identify.clone();
        if let Some(x) = &r.extrinsics {
            io.extrinsics = x.value;
        }
        let bias = est.and_then(|e| simex_bias(&data, drive.drive_starts(), &r.theta, &io, e, o.seed));
        let f = |v: [f64; 4]| v.iter().map(|x| format!("{x:+.1}")).collect::<Vec<_>>().join(" ");
        table.row([
            seed.to_string(),
            summary.regime.to_string(),
            format!("{:.3} / {:.3} %", est.unwrap_or(0.0) * 100.0, noise.wheel_white_rel_sigma * 100.0),
            f(err),
            bias.map_or("–".into(), |b| f(std::array::from_fn(|i| b[i] / s[i]))),
            format!("{}", r.verdict.level),
        ]);
    }
    print!("{table}");
    let cov: Vec<String> = covered.iter().map(|c| format!("{:.0} %", 100.0 * *c as f64 / worlds as f64)).collect();
    let geo: Vec<String> = width.iter().map(|w| format!("{:.4e}", Summary::of(w).mean.exp())).collect();
    println!(
        "{worlds} worlds; coverage of ±1.96σ (c_e, c_d, t_r, d): {}; accepted beyond 3σ: {accepted_beyond}; geometric mean σ: {}",
        cov.join(", "),
        geo.join(", ")
    );
    Ok(())
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    if args.positional().first().map(String::as_str) == Some("real") {
        return real();
    }
    if args.positional().first().map(String::as_str) == Some("worlds") {
        return worlds(args.pos(1, 1)?, args.pos(2, 100)?, args.pos(3, 12.0)?);
    }
    let seeds: u64 = args.pos(0, 20)?;
    let km: f64 = args.pos(1, 12.0)?;
    let presets: String = args.pos(2, "paper,white,coloured,high".to_string())?;
    let opts = CalibrationOptions { method: Method::BatchGn, ..Default::default() };
    let mut table = Table::new(&[
        "preset",
        "c_e: error / predicted (σ)",
        "c_d",
        "t_r",
        "d",
        "σ_w est / sim",
        "doubtful by the check",
        "accepted beyond 3σ (before → with the check)",
    ]);
    for preset in presets.split(',') {
        let (mut err, mut pred) = (vec![Vec::new(); 4], vec![Vec::new(); 4]);
        let (mut sw, mut flagged, mut before, mut after) = (Vec::new(), 0, 0, 0);
        let sim_sw = odocal_lab::noise_preset(preset)?.wheel_white_rel_sigma;
        for seed in 1..=seeds {
            let out = simulate_preset(preset, km, seed)?;
            let drive = &out.drive;
            let detailed = calibrate_detailed(drive, None, &opts, None)?;
            let r = &detailed.report;
            let sigma: [Option<f64>; 4] = r.result_sigma().into();
            let truth = <[f64; 4]>::from(out.sidecar.theta_true);
            let theta = <[f64; 4]>::from(r.theta);
            let data: Vec<SegmentData> = detailed.selected.iter().map(|s| SegmentData::new(drive, s)).collect();
            let est = wheel_white_noise(&data, &r.theta).unwrap_or(0.0);
            sw.push(est);
            let bias = simex_bias(&data, drive.drive_starts(), &r.theta, &IdentifyOptions::default(), est, opts.seed)
                .unwrap_or([0.0; 4]);
            let mut worst: f64 = 0.0;
            for i in 0..4 {
                let s = sigma[i].unwrap_or(f64::NAN);
                err[i].push((theta[i] - truth[i]) / s);
                pred[i].push(bias[i] / s);
                worst = worst.max(((theta[i] - truth[i]) / s).abs());
            }
            let checked = r.verdict.reasons.iter().any(|x| matches!(x, VerdictReason::InputNoiseBias { .. }));
            let others = r.verdict.reasons.iter().any(|x| !matches!(x, VerdictReason::InputNoiseBias { .. }));
            flagged += usize::from(checked);
            before += usize::from(worst > 3.0 && !others);
            after += usize::from(worst > 3.0 && r.verdict.level == VerdictLevel::Accepted);
        }
        let cell = |i: usize| {
            let (e, p) = (Summary::of(&err[i]), Summary::of(&pred[i]));
            format!("{:+.2} ± {:.2} / {:+.2}", e.mean, e.se(), p.mean)
        };
        table.row([
            preset.to_string(),
            cell(0),
            cell(1),
            cell(2),
            cell(3),
            format!("{:.2} / {:.2} %", Summary::of(&sw).mean * 100.0, sim_sw * 100.0),
            format!("{flagged} of {seeds}"),
            format!("{before} → {after}"),
        ]);
        eprintln!("{preset} done ({})", NAMES.join(", "));
    }
    print!("{table}");
    Ok(())
}
