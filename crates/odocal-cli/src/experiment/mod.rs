//! `odocal experiment`: the paper's §6 on a simulated (or given) drive in one
//! command. The numbers come from [`odocal::experiment::run`]; this module
//! loads or simulates the drive and writes them as `report.md` ([`markdown`]),
//! SVG figures ([`figures`]) and `experiment.json`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Args;
use odocal::compensate::{QpOptions, SolverKind};
use odocal::experiment::{self, Experiment, ExperimentOptions, ExperimentTiming};
use odocal::settings::Settings;
use odocal::sim::{self, NoiseOptions, SimOptions};
use odocal::{CalibrationOptions, Drive, Method, ReachableOptions, Theta, ThreeStepOptions};
use serde::Serialize;

use crate::output::{refuse_stdout, Files};
use crate::progress::Bars;

mod figures;
mod markdown;
mod summary;

/// Arguments of `odocal experiment`.
#[derive(Args)]
pub struct ExperimentArgs {
    /// Seed of the simulation and of the random batches.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulated route length, km.
    #[arg(long, default_value_t = 24.0, value_parser = crate::simulate::route_length_km)]
    pub length_km: f64,
    /// Noise preset of the simulation: paper, off, white (wheel white noise only), high or random:N.
    #[arg(long, default_value = "paper", value_parser = crate::simulate::noise_preset)]
    pub noise: String,
    /// Run on this drive (canonical CSV) instead of simulating one; the truth
    /// is taken from its sidecar JSON when there is one.
    #[arg(long)]
    pub drive: Option<PathBuf>,
    /// QP solver for input compensation: structured or clarabel.
    #[arg(long, default_value = "structured")]
    pub qp_solver: SolverKind,
    /// Number of random batches of N = 10 segments of the first fit.
    #[arg(long, default_value_t = 50)]
    pub batches: usize,
    /// Output directory (created if missing). A directory that already
    /// holds an experiment's files (report.md, experiment.json, the
    /// figures) is refused, unless --force.
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the files of an experiment already in --out (other files
    /// there are left alone).
    #[arg(long)]
    pub force: bool,
}

/// Where the drive came from.
#[derive(Debug, Clone, Serialize)]
struct DriveInfo {
    source: String,
    samples: usize,
    distance_km: f64,
    sample_time_s: f64,
    seed: Option<u64>,
    noise: Option<String>,
    wheel_rotation_rel_error_rms: Option<f64>,
}

/// Wall time, s: the library's stages plus simulation and figures.
#[derive(Debug, Clone, Default, Serialize)]
struct Timing {
    simulate: f64,
    #[serde(flatten)]
    stages: ExperimentTiming,
    figures: f64,
    total: f64,
}

/// What the command adds to the library's numbers.
struct Outputs {
    drive: DriveInfo,
    figures: Vec<String>,
    timing: Timing,
}

/// The drive of the experiment, its true θ and simulator noise when known, and
/// where it came from.
type DriveAndTruth = (Drive, Option<Theta>, Option<NoiseOptions>, DriveInfo);

/// Runs the experiment.
pub fn run(a: ExperimentArgs, bars: &Bars) -> Result<()> {
    let t_total = Instant::now();
    let mut timing = Timing::default();
    check_counts(&a)?;
    check_out_dir(&a)?;

    let t = Instant::now();
    let (drive, theta_true, noise, info) = match &a.drive {
        Some(path) => read_drive(path)?,
        None => simulate_drive(&a, bars)?,
    };
    timing.simulate = t.elapsed().as_secs_f64();

    let method = Method::ThreeStep(ThreeStepOptions {
        initial_batches: a.batches,
        qp: QpOptions::from(a.qp_solver),
        ..Default::default()
    });
    let calibration = CalibrationOptions { method, seed: a.seed, ..Default::default() };
    let reachable = ReachableOptions { seed: a.seed, ..ReachableOptions::around(&calibration.theta0) };
    let cb = |e| bars.event(e);
    let opts = ExperimentOptions { calibration, reachable, noise };
    let exp = experiment::run(&drive, theta_true.as_ref(), &opts, Some(&cb)).map_err(own_hints)?;
    bars.finish();
    timing.stages = exp.timing_s.clone();

    let t = Instant::now();
    let svgs = figures::render_figures(&exp)?;
    timing.figures = t.elapsed().as_secs_f64();
    timing.total = t_total.elapsed().as_secs_f64();
    let figures = svgs.iter().map(|(name, _)| name.to_string()).collect();
    let outputs = Outputs { drive: info, figures, timing };
    let (json_path, md_path) = (a.out.join(EXPERIMENT_JSON), a.out.join(REPORT_MD));
    let mut files: Vec<(PathBuf, String)> = svgs.into_iter().map(|(name, svg)| (a.out.join(name), svg)).collect();
    files.push((json_path.clone(), json_text(&exp, &outputs)?));
    files.push((md_path.clone(), markdown::report_md(&exp, &outputs)));
    // The folder is made once there is something to put in it: a drive that
    // cannot be read or an experiment that fails leaves none behind. The
    // files are written as one: a failed write leaves those of an earlier
    // experiment there (--force) as they were.
    std::fs::create_dir_all(&a.out).with_context(|| format!("--out {}: cannot create the folder", a.out.display()))?;
    let files: Vec<(&Path, &str)> = files.iter().map(|(p, t)| (p.as_path(), t.as_str())).collect();
    odocal::output::write_texts(&files, true)?;

    for l in crate::io::summarize(&exp.warnings, SHOWN_WARNINGS) {
        eprintln!("warning: {l}");
    }
    println!(
        "θ_B,F Ē_p {:.3} m; reachable minimum {:.3} m; θ_nom {:.3} m{}",
        exp.final_estimate.mean_position_error_m,
        exp.reachable_minimum.scored.mean_position_error_m,
        exp.nominal.mean_position_error_m,
        exp.truth.map(|t| format!("; θ_true {:.3} m", t.mean_position_error_m)).unwrap_or_default()
    );
    println!("wrote {} and {} ({:.1} s)", md_path.display(), json_path.display(), outputs.timing.total);
    Ok(())
}

/// The report's file name in `--out`.
const REPORT_MD: &str = "report.md";
/// The JSON's file name in `--out`.
const EXPERIMENT_JSON: &str = "experiment.json";

/// The library's errors with the hints `experiment` can follow: it has
/// no `--fix`, `--min-yaw-rate` or `--validation-length` (it runs the
/// paper's settings), so those hints become a longer or turning drive, or
/// `calibrate`.
fn own_hints(e: odocal::Error) -> anyhow::Error {
    const FIX_HINT: &str = "Hold them at θ_0 (--fix c_d,t_r,d) and select every segment (--min-yaw-rate 0) to \
                            calibrate c_e alone";
    const LENGTH_HINT: &str = "give a longer drive or a shorter validation_length (--validation-length)";
    match e {
        odocal::Error::NotObservable { params, reason } if reason.contains(FIX_HINT) => {
            let reason = reason.replace(
                FIX_HINT,
                "experiment runs the paper's settings, which estimate them: give a drive that turns (another \
                 --drive, or none to simulate one), or calibrate c_e alone with `odocal calibrate DRIVE --fix \
                 c_d,t_r,d --min-yaw-rate 0`",
            );
            odocal::Error::NotObservable { params, reason }.into()
        }
        odocal::Error::NoSegments(reason) if reason.contains(LENGTH_HINT) => {
            let hint = "give a longer drive (a longer --length-km, or another --drive); experiment's validation \
                        segments are the paper's";
            odocal::Error::NoSegments(reason.replace(LENGTH_HINT, hint)).into()
        }
        e => e.into(),
    }
}

/// `--batches` checked as `calibrate` checks it: at least 1 and at most
/// its ceiling, a usage error naming the flag.
fn check_counts(a: &ExperimentArgs) -> Result<()> {
    let method = Some(Method::ThreeStep(ThreeStepOptions::default()));
    crate::args::check_counts(Settings { method, batches: Some(a.batches), ..Default::default() })
}

/// Refuses an `--out` that is stdout, or that holds an experiment's files
/// already (unless `--force`), and outputs that would overwrite the drive
/// or its sidecar.
fn check_out_dir(a: &ExperimentArgs) -> Result<()> {
    refuse_stdout("--out", &a.out, "the experiment writes a folder of files")?;
    if a.out.exists() && !a.out.is_dir() {
        bail!("--out {}: is a file, not a folder; give a folder for the experiment's files", a.out.display());
    }
    let names = [REPORT_MD, EXPERIMENT_JSON].into_iter().chain(figures::FIGURES);
    let outputs: Vec<PathBuf> = names.map(|n| a.out.join(n)).collect();
    if !a.force {
        if let Some(p) = outputs.iter().find(|p| p.exists()) {
            bail!(
                "--out {}: holds an experiment already ({} exists); give a new folder, or add --force to replace \
                 the experiment's files there",
                a.out.display(),
                p.display()
            );
        }
    }
    let mut files = Files::default();
    files.creates_folder();
    if let Some(d) = &a.drive {
        files.drive("the --drive", d);
    }
    for p in &outputs {
        let name = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        files.output(format!("--out's {name}"), Some(p));
    }
    files.check()
}

/// A drive CSV with the truth from its simulator sidecar, when it has one
/// that records the drive's fingerprint.
fn read_drive(path: &Path) -> Result<DriveAndTruth> {
    let (drive, warnings) = Drive::read_csv(path)?;
    for w in warnings {
        eprintln!("warning: {w}");
    }
    let sidecar = crate::io::load_truth(path, &drive);
    let info = DriveInfo {
        source: path.display().to_string(),
        samples: drive.len(),
        distance_km: drive.distance_m() / 1e3,
        sample_time_s: drive.sample_time_s(),
        seed: sidecar.as_ref().map(|s| s.settings.seed),
        noise: None,
        wheel_rotation_rel_error_rms: sidecar.as_ref().map(|s| s.stats.wheel_rotation_rel_error_rms),
    };
    let noise = sidecar.as_ref().map(|s| s.settings.noise.clone());
    Ok((drive, sidecar.map(|s| s.theta_true), noise, info))
}

/// A simulated drive of the arguments' seed, length and noise preset.
fn simulate_drive(a: &ExperimentArgs, bars: &Bars) -> Result<DriveAndTruth> {
    let noise = a.noise.parse::<NoiseOptions>()?;
    let o = SimOptions { seed: a.seed, length_km: a.length_km, noise, ..SimOptions::paper(a.seed) };
    bars.stage("simulating");
    let out = sim::simulate(&o).map_err(crate::simulate::flag_error)?;
    bars.finish();
    let s = &out.sidecar.stats;
    let info = DriveInfo {
        source: format!("simulated (seed {}, {} km, noise '{}')", a.seed, a.length_km, a.noise),
        samples: s.samples,
        distance_km: s.distance_m / 1e3,
        sample_time_s: out.drive.sample_time_s(),
        seed: Some(a.seed),
        noise: Some(a.noise.clone()),
        wheel_rotation_rel_error_rms: Some(s.wheel_rotation_rel_error_rms),
    };
    let noise = out.sidecar.settings.noise.clone();
    Ok((out.drive, Some(out.sidecar.theta_true), Some(noise), info))
}

/// The text of `experiment.json`: the library's numbers with the summary
/// rows ([`summary`]), the drive, the figures and the timing.
fn json_text(exp: &Experiment, outputs: &Outputs) -> Result<String> {
    let mut json = serde_json::to_value(exp)?;
    if let Some(obj) = json.as_object_mut() {
        for (key, _, s) in summary::summaries(exp) {
            obj.insert(key.into(), serde_json::to_value(s)?);
        }
        obj.insert("schema_version".into(), odocal::REPORT_SCHEMA_VERSION.into());
        obj.insert("drive".into(), serde_json::to_value(&outputs.drive)?);
        obj.insert("figures".into(), serde_json::to_value(&outputs.figures)?);
        obj.insert("timing_s".into(), serde_json::to_value(&outputs.timing)?);
    }
    Ok(serde_json::to_string_pretty(&json)?)
}

/// Warnings of one kind printed on stderr (report.md lists all).
const SHOWN_WARNINGS: usize = 3;

/// A parameter's name, plot unit and value in that unit.
type Param = (&'static str, &'static str, fn(&Theta) -> f64);

/// The θ entries with their plot units (c_d and d in mm).
const PARAMS: [Param; 4] = [
    ("c_e", "m", |t| t.c_e),
    ("c_d", "mm", |t| t.c_d * 1e3),
    ("t_r", "m", |t| t.t_r),
    ("d", "mm/(m/s²)", |t| t.d * 1e3),
];
