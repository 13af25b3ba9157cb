//! The verdict's check of batch Gauss-Newton's errors-in-variables bias
//! (`input_noise_bias`, odocal's `calibrate::input_noise`) on simulated
//! drives with a known truth (docs/validation.md, "Batch G-N's input-noise
//! bias").
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
//! predicted bias over the σ for the next drive.

use odocal::identify::IdentifyOptions;
use odocal::research::{calibrate_detailed, simex_bias, wheel_white_noise};
use odocal::segment::SegmentData;
use odocal::{CalibrationOptions, Method, VerdictLevel, VerdictReason};
use odocal_lab::{simulate_preset, Args, Res, Summary, Table};

const USAGE: &str = "gn_simex [SEEDS 20] [KM 12] [PRESETS paper,white,coloured,high]";

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
    let mut o = CalibrationOptions { method: Method::BatchGn(Default::default()), ..Default::default() };
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

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    if args.positional().first().map(String::as_str) == Some("real") {
        return real();
    }
    let seeds: u64 = args.pos(0, 20)?;
    let km: f64 = args.pos(1, 12.0)?;
    let presets: String = args.pos(2, "paper,white,coloured,high".to_string())?;
    let opts = CalibrationOptions { method: Method::BatchGn(Default::default()), ..Default::default() };
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
