//! The `odocal` command-line tool: a thin layer over the `odocal` library.
//!
//! Human-readable output goes to stdout, progress bars and warnings to
//! stderr; errors are one line on stderr and exit code 1 (2 for usage
//! errors). `calibrate` exits with [`EXIT_REJECTED`] when the verdict is
//! `rejected` (the report is still written).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use odocal::calibrate::settings::{ManifestSettings, SettingUse};
use odocal::drive::ExtraColumn;
use odocal::sim::{self, NoiseOptions, SimOptions, SimSidecar};
use odocal::{
    drive::segment, CalibrationOptions, CalibrationReport, Drive, FinalSegments, Holdout, Method, ParamSet, QpOptions,
    SolverKind, Theta, ThreeStepOptions, VerdictLevel, Warning,
};

mod experiment;
mod inspect;
mod progress;
mod report;
mod settings;

#[derive(Parser)]
#[command(
    name = "odocal",
    version,
    about = "Wheel-odometry model calibration with input compensation by optimal control"
)]
struct Cli {
    /// No progress bars.
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a drive with known true parameters (writes DRIVE.csv and DRIVE.json).
    Simulate(SimulateArgs),
    /// Calibrate θ from a drive (canonical CSV).
    Calibrate(CalibrateArgs),
    /// Mean position error Ē_p of a θ on a drive's validation segments.
    Validate(ValidateArgs),
    /// Write a drive with compensated wheel rotations beside the measured ones.
    Compensate(CompensateArgs),
    /// Simulate the default 24 km drive, calibrate it and compare with the truth.
    Demo(DemoArgs),
    /// Reproduce the paper's §6 on a simulated (or given) drive: report.md, SVG figures, experiment.json.
    Experiment(ExperimentArgs),
    /// Import a multi-stream real log described by a TOML manifest into a canonical drive CSV.
    Import(ImportArgs),
    /// List a ROS 2 bag's (MCAP) topics, types, counts and rates, and the manifest columns of each.
    Inspect(inspect::InspectArgs),
}

#[derive(Args)]
struct ImportArgs {
    /// The drive manifest (TOML; see examples/README.md).
    manifest: PathBuf,
    /// Output canonical CSV.
    #[arg(long)]
    out: PathBuf,
    /// Write the import report as JSON here ("-" for stdout).
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Args)]
struct SimulateArgs {
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Route length, km.
    #[arg(long, default_value_t = 24.0)]
    length_km: f64,
    /// Output CSV; the sidecar JSON is written beside it.
    #[arg(long)]
    out: PathBuf,
    /// Noise preset: paper, off, white (white wheel noise only) or high.
    #[arg(long, default_value = "paper")]
    noise: String,
    /// True θ as c_e,c_d,t_r,d in SI units (c_d in m, d in m per m/s²), or a
    /// parameter file (.yaml, .yml, .json, as --params-out writes).
    #[arg(long, allow_hyphen_values = true)]
    theta: Option<ThetaArg>,
    /// Integration substeps per output sample (1 makes the model exact).
    #[arg(long)]
    substeps: Option<usize>,
}

#[derive(Args, Clone)]
struct CalibrationArgs {
    /// Calibration method: three-step, batch-gn or eiv (errors-in-variables
    /// filter over the whole drive, started from batch-gn on all segments;
    /// falls back to that batch-gn when its consistency checks fail; the
    /// default); three-step is the paper's method.
    #[arg(long, default_value = "eiv")]
    method: Method,
    /// Seed of the random batches.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Three-step: QP solver for input compensation, structured (default) or clarabel.
    #[arg(long)]
    qp_solver: Option<SolverKind>,
    /// Initial guess θ_0 as c_e,c_d,t_r,d (SI), or a parameter file (.yaml,
    /// .yml, .json, as --params-out writes: its θ; e.g. the last calibration).
    #[arg(long, allow_hyphen_values = true)]
    theta0: Option<ThetaArg>,
    /// Parameters held fixed at θ_0, comma separated (e.g. c_d,t_r,d).
    #[arg(long)]
    fix: Option<ParamSet>,
    /// Also estimate the pose reference's extrinsics with θ: lever-arm
    /// and/or heading-offset (or lever_x, lever_y, heading_offset). The
    /// validation then compares the model's reference point with the
    /// reference. Batch-gn, three-step (steps 1 and 3) and eiv (two-stage:
    /// its batch G-N start estimates them, the filter holds them).
    #[arg(long)]
    estimate: Option<ParamSet>,
    /// Lever arm X,Y (m, x forward, y left) of the pose reference from the
    /// rear-axle centre: held at this value, or the start of --estimate. Default 0,0.
    #[arg(long, allow_hyphen_values = true)]
    lever_arm: Option<String>,
    /// Heading offset (rad) of the pose reference (reference heading minus
    /// vehicle heading): held, or the start of --estimate. Default 0.
    #[arg(long, allow_hyphen_values = true)]
    heading_offset: Option<f64>,
    /// Minimum peak yaw rate for a segment to be selected, rad/s.
    #[arg(long)]
    min_yaw_rate: Option<f64>,
    /// Keep the paper's turning-only segment selection even when every
    /// selected segment turns the same way (default: the straight segments
    /// are added, with a warning, because one-way turns confound c_d with
    /// t_r). Three-step and batch-gn; wins over a manifest's
    /// `[calibration] keep_one_way`.
    #[arg(long)]
    keep_one_way: bool,
    /// Calibration segment length K, samples.
    #[arg(long)]
    segment_length: Option<usize>,
    /// Calibration segment stride, samples.
    #[arg(long)]
    segment_stride: Option<usize>,
    /// Validation segment length K_v, samples.
    #[arg(long)]
    validation_length: Option<usize>,
    /// Three-step, step 1: number of random batches.
    #[arg(long)]
    batches: Option<usize>,
    /// Three-step, step 1: segments per batch.
    #[arg(long)]
    batch_size: Option<usize>,
    /// Three-step, step 1: number of θ_B,I picked.
    #[arg(long)]
    picks: Option<usize>,
    /// Three-step, step 3: "all" selected segments or a number of random ones.
    #[arg(long)]
    final_segments: Option<FinalSegments>,
    /// Maximum Gauss-Newton iterations.
    #[arg(long)]
    max_iterations: Option<usize>,
    /// EIV: starting noise model, a TOML file of noise-model fields (e.g.
    /// `wheel_white_rel_sigma = 0.01`; missing fields keep the production-car
    /// defaults; `known = ["heading_white"]` holds stated levels; see
    /// `odocal::calibrate::eiv::read_noise_model`).
    #[arg(long)]
    noise_model: Option<PathBuf>,
    /// EIV: noise sources whose level in the starting model is known (e.g.
    /// from the INS datasheet) and held, not estimated: wheel-white,
    /// wheel-common, wheel-differential, pose-white, pose-drift,
    /// heading-white (comma list; adds to a noise model's `known`).
    #[arg(long, value_delimiter = ',')]
    known_noise: Vec<odocal::eiv::NoiseSource>,
    /// EIV: use the starting noise model as is instead of estimating its scales.
    #[arg(long)]
    fix_noise: bool,
    /// EIV: keep the EIV result even when its consistency checks fail
    /// (default: fall back to batch G-N on all segments).
    #[arg(long)]
    no_fallback: bool,
    /// EIV: filter window length, samples.
    #[arg(long)]
    eiv_window: Option<usize>,
    /// EIV: how encoder quantisation enters the noise model: process (a
    /// white rate noise that accumulates), measurement (a pose noise) or
    /// counting (the exact counting error, two more filter states, about
    /// 1.2× the time). Default: the library's (`EivOptions::quantisation`).
    #[arg(long, value_name = "MODEL",
          value_parser = library_enum::<odocal::eiv::QuantisationModel>(&["process", "measurement", "counting"]))]
    quantisation: Option<odocal::eiv::QuantisationModel>,
    /// EIV: the quantisation step q: scaled (estimated with the white wheel
    /// noise from the noise model's q), given (the noise model's q, held)
    /// or from-readings (read off the wheel readings when they lie on the
    /// lattice of counted ticks, else scaled). Default: the library's
    /// (`EivOptions::quantisation_level`).
    #[arg(long, value_name = "LEVEL",
          value_parser = library_enum::<odocal::eiv::QuantisationLevel>(&["scaled", "given", "from-readings"]))]
    quantisation_level: Option<odocal::eiv::QuantisationLevel>,
    /// EIV: the a_y and β noise scaled with the white wheel noise (tied) or
    /// held at the noise model's σ (stated: the IMU's and the sideslip
    /// source's noise, e.g. from `--noise-model`). Default: the library's
    /// (`EivOptions::lateral_noise`).
    #[arg(long, value_name = "SCALE",
          value_parser = library_enum::<odocal::eiv::LateralNoise>(&["tied", "stated"]))]
    lateral_noise: Option<odocal::eiv::LateralNoise>,
    /// EIV: the reference heading's white noise scaled together with the
    /// position noise (tied) or by a scale of its own (separate). Default:
    /// the library's (`EivOptions::heading_scale`).
    #[arg(long, value_name = "SCALE",
          value_parser = library_enum::<odocal::eiv::HeadingScale>(&["tied", "separate"]))]
    heading_noise: Option<odocal::eiv::HeadingScale>,
    /// EIV: parametric bootstrap with B replicates (re-simulate the fitted
    /// noise, re-fit B times): percentile intervals and the estimator's own
    /// bias in the report; about B extra fits of time.
    #[arg(long, value_name = "B")]
    bootstrap: Option<usize>,
    /// EIV: seed of the bootstrap's replicates (--bootstrap, and the bias
    /// correction: the default one and --correct-bias, --correct-c-e-bias).
    #[arg(long, default_value_t = 0)]
    bootstrap_seed: u64,
    /// EIV: subtract the estimator's own c_e bias, estimated by a
    /// parametric bootstrap with B replicates (seed --bootstrap-seed);
    /// about B extra fits of time. The default fit has no c_e bias left for
    /// it to remove (docs/study.md). It replaces the default correction of
    /// every parameter (see --correct-bias).
    #[arg(long, value_name = "B", conflicts_with_all = ["correct_bias", "no_bias_correction"])]
    correct_c_e_bias: Option<usize>,
    /// EIV: replicates B of the bias correction that is on by default
    /// (B = 4): the estimator's own bias is subtracted from every
    /// parameter, estimated by a parametric bootstrap of B re-simulations
    /// in antithetic pairs (B even; seed --bootstrap-seed) on the smoothed
    /// trajectory, each holding the fitted noise model; θ's σ includes its
    /// Monte Carlo error. It removes the bias heavy wheel noise puts on t_r
    /// (simulated `high` preset, 20 drives: t_r +1.10 % → +0.46 %, every
    /// parameter within |t| ≤ 1.9, 94 % coverage) at 1.3–1.5× the time of
    /// the uncorrected fit (B = 4). It runs only for a fit that is kept.
    #[arg(long, value_name = "B", value_parser = parse_even_replicates, conflicts_with = "no_bias_correction")]
    correct_bias: Option<usize>,
    /// EIV: return the profile cost's root as is, without the default bias
    /// correction (see --correct-bias).
    #[arg(long)]
    no_bias_correction: bool,
    /// Hold out half of the drive (by time) for validation and calibrate on
    /// the other half: first-half or second-half (the half held out).
    #[arg(long)]
    holdout: Option<HalfArg>,
    /// Validate on other drives of the same vehicle (CSV or manifest;
    /// repeat the flag or separate with commas) instead of the calibration
    /// drive: Ē_p per drive and over all of them.
    #[arg(long, conflicts_with = "holdout", value_delimiter = ',')]
    validate_on: Vec<PathBuf>,
    /// Hold at θ_0 the parameters the data cannot determine (named by the
    /// observability check) instead of estimating them; with no turning
    /// segment, hold c_d, t_r, d and use every segment.
    #[arg(long)]
    auto_fix: bool,
    /// Write the calibrated parameters with their 1σ, units, verdict and
    /// provenance to this file: a ROS 2 parameter file (.yaml/.yml) or JSON (.json).
    #[arg(long)]
    params_out: Option<PathBuf>,
    /// ROS node name of the parameter file.
    #[arg(long, default_value = "odocal")]
    params_node: String,
    /// Also write the parameters under a consumer's keys: odocal (none) or
    /// diff_drive_controller (wheel_separation, wheel_radius, radius multipliers).
    #[arg(long, default_value = "odocal")]
    params_mapping: odocal::io::param_file::ParamMapping,
    /// Write a self-contained HTML report (verdict, θ, map, per-segment errors,
    /// residuals, warnings) to this file.
    #[arg(long)]
    report: Option<PathBuf>,
}

/// A clap parser of a library enum named on the command line: the names
/// offered (and listed by `--help`) are `names`, the mapping is the
/// library's `FromStr`, so the CLI and the library (and Python, which uses
/// the same `FromStr`) cannot drift apart.
fn library_enum<T>(names: &'static [&'static str]) -> impl clap::builder::TypedValueParser<Value = T>
where
    T: std::str::FromStr<Err = odocal::Error> + Clone + Send + Sync + 'static,
{
    use clap::builder::TypedValueParser;
    clap::builder::PossibleValuesParser::new(names).try_map(|s| s.parse::<T>())
}

/// The half of the drive `--holdout` holds out.
#[derive(Clone, Copy, clap::ValueEnum)]
enum HalfArg {
    FirstHalf,
    SecondHalf,
}

impl CalibrationArgs {
    /// The method with the flags that belong to it; a flag of another
    /// method is an error (batch-gn would otherwise ignore it silently).
    fn method(&self) -> Result<Method> {
        let three_step_flags = [
            ("--batches", self.batches.is_some()),
            ("--batch-size", self.batch_size.is_some()),
            ("--picks", self.picks.is_some()),
            ("--final-segments", self.final_segments.is_some()),
            ("--qp-solver", self.qp_solver.is_some()),
        ];
        let eiv_flags = [
            ("--noise-model", self.noise_model.is_some()),
            ("--known-noise", !self.known_noise.is_empty()),
            ("--fix-noise", self.fix_noise),
            ("--no-fallback", self.no_fallback),
            ("--eiv-window", self.eiv_window.is_some()),
            ("--quantisation", self.quantisation.is_some()),
            ("--quantisation-level", self.quantisation_level.is_some()),
            ("--lateral-noise", self.lateral_noise.is_some()),
            ("--heading-noise", self.heading_noise.is_some()),
            ("--bootstrap", self.bootstrap.is_some()),
            ("--bootstrap-seed", self.bootstrap_seed != 0),
            ("--correct-c-e-bias", self.correct_c_e_bias.is_some()),
            ("--correct-bias", self.correct_bias.is_some()),
            ("--no-bias-correction", self.no_bias_correction),
        ];
        let reject = |flags: &[(&str, bool)], owner: &str, other: &Method| -> Result<()> {
            let given: Vec<&str> = flags.iter().filter(|f| f.1).map(|f| f.0).collect();
            if !given.is_empty() {
                bail!(
                    "{} appl{} to --method {owner} only, not to --method {other}",
                    given.join(", "),
                    if given.len() == 1 { "ies" } else { "y" }
                );
            }
            Ok(())
        };
        if !matches!(self.method, Method::Eiv(_)) {
            reject(&eiv_flags, "eiv", &self.method)?;
        }
        Ok(match &self.method {
            Method::ThreeStep(defaults) => {
                let mut o: ThreeStepOptions = defaults.clone();
                if let Some(v) = self.batches {
                    o.initial_batches = v;
                }
                if let Some(v) = self.batch_size {
                    o.initial_batch_size = v;
                }
                if let Some(v) = self.picks {
                    o.picks = v;
                }
                if let Some(v) = self.final_segments {
                    o.final_segments = v;
                }
                if let Some(v) = self.qp_solver {
                    o.qp.solver = v;
                }
                Method::ThreeStep(o)
            }
            Method::Eiv(defaults) => {
                reject(&three_step_flags, "three-step", &self.method)?;
                if self.keep_one_way {
                    bail!("--keep-one-way applies to the segment-selecting methods (three-step, batch-gn), not to --method eiv");
                }
                let mut o = defaults.clone();
                if let Some(p) = &self.noise_model {
                    odocal::calibrate::eiv::read_noise_model(p)?.apply(&mut o.filter);
                }
                // A manifest's [noise] `known` adds to these when it applies.
                o.filter.hold_known(&self.known_noise);
                o.filter.fix_noise = self.fix_noise;
                o.fallback = !self.no_fallback;
                if let Some(v) = self.eiv_window {
                    o.filter.window_samples = v;
                }
                if let Some(q) = self.quantisation {
                    o.filter.quantisation = q;
                }
                if let Some(l) = self.quantisation_level {
                    o.filter.quantisation_level = l;
                }
                if let Some(l) = self.lateral_noise {
                    o.filter.lateral_noise = l;
                }
                if let Some(h) = self.heading_noise {
                    o.filter.heading_scale = h;
                }
                if let Some(b) = self.correct_c_e_bias {
                    o.filter.bias_correction = odocal::eiv::BiasCorrection::Bootstrap {
                        replicates: b,
                        seed: self.bootstrap_seed,
                        all_parameters: false,
                    };
                }
                // The default bias correction (B = 4) takes the bootstrap seed;
                // --correct-bias sets B, --no-bias-correction turns it off.
                o.correct_bias = if self.no_bias_correction {
                    None
                } else {
                    let replicates = self.correct_bias.unwrap_or(odocal::calibrate::DEFAULT_BIAS_REPLICATES);
                    Some(odocal::calibrate::CorrectBias { replicates, seed: self.bootstrap_seed })
                };
                if let Some(b) = self.bootstrap {
                    o.bootstrap = Some(odocal::eiv::BootstrapOptions {
                        replicates: b,
                        seed: self.bootstrap_seed,
                        ..Default::default()
                    });
                }
                Method::Eiv(o)
            }
            other => {
                reject(&three_step_flags, "three-step", other)?;
                other.clone()
            }
        })
    }

    /// The options from the flags and, where a flag is not given, the
    /// manifest's settings (what became of each is returned).
    fn options(&self, manifest: Option<&ManifestSettings>) -> Result<(CalibrationOptions, Vec<SettingUse>)> {
        let mut o = CalibrationOptions {
            method: self.method()?,
            seed: self.seed,
            auto_fix: self.auto_fix,
            ..Default::default()
        };
        if let Some(t) = &self.theta0 {
            o.theta0 = t.theta;
        }
        let uses = manifest.map(|m| m.apply(&mut o, settings::given(self))).unwrap_or_default();
        if let Some(e) = self.estimate {
            let theta = e.intersection(ParamSet::THETA);
            if !theta.is_empty() {
                bail!(
                    "--estimate takes lever-arm, heading-offset (or lever_x, lever_y, heading_offset), not {theta}: \
                     θ is estimated by default (hold parameters with --fix)"
                );
            }
            o.identify.free = o.identify.free.union(e);
        }
        if let Some(s) = &self.lever_arm {
            let v: Vec<&str> = s.split(',').map(str::trim).collect();
            let parsed: Vec<f64> = v.iter().filter_map(|x| x.parse::<f64>().ok()).collect();
            if v.len() != 2 || parsed.len() != 2 {
                bail!("--lever-arm takes X,Y in metres (x forward, y left), got '{s}'");
            }
            o.identify.extrinsics.lever_x = parsed[0];
            o.identify.extrinsics.lever_y = parsed[1];
        }
        if let Some(v) = self.heading_offset {
            o.identify.extrinsics.heading_offset = v;
            o.hold_stated_heading_offset();
        }
        for p in self.fix.unwrap_or_default().iter() {
            o.hold(p);
        }
        if let Some(v) = self.min_yaw_rate {
            o.segments.min_peak_yaw_rate_rad_per_s = v;
        }
        if self.keep_one_way {
            o.keep_one_way_selection = true;
        }
        if let Some(v) = self.segment_length {
            o.segments.length_steps = v;
        }
        if let Some(v) = self.segment_stride {
            o.segments.stride_steps = v;
        }
        if let Some(v) = self.validation_length {
            o.validation.length_steps = v;
            o.validation.stride_steps = (v / 2).max(1);
        }
        if let Some(v) = self.max_iterations {
            o.identify.max_iterations = v;
        }
        o.validate()?;
        Ok((o, uses))
    }
}

#[derive(Args)]
struct CalibrateArgs {
    /// The drive: a canonical CSV (SPEC §2) or a drive manifest (.toml).
    /// Several drives of one vehicle are fitted jointly (segments never
    /// span two drives; their sample times must agree).
    #[arg(required = true, num_args = 1..)]
    drive: Vec<PathBuf>,
    #[command(flatten)]
    calibration: CalibrationArgs,
    /// Write the JSON report here ("-" for stdout, which replaces the human output).
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Args)]
struct ValidateArgs {
    /// The drive: a canonical CSV or a drive manifest (.toml).
    drive: PathBuf,
    /// θ as c_e,c_d,t_r,d (SI), or a parameter file (.yaml, .yml, .json) as
    /// `calibrate --params-out` writes it: its θ and the reference extrinsics
    /// it estimated (held ones give way to the drive's manifest [reference]).
    #[arg(long, allow_hyphen_values = true)]
    theta: ThetaArg,
    /// Validation segment length K_v, samples (stride K_v/2).
    #[arg(long)]
    validation_length: Option<usize>,
    /// Also search the reachable minimum of Ē_p (global particle swarm over a
    /// box around θ_0, refined by Nelder-Mead).
    #[arg(long)]
    reachable_minimum: bool,
    /// Centre of the reachable-minimum search box (default the paper's θ_0;
    /// c_e,c_d,t_r,d or a parameter file).
    #[arg(long, allow_hyphen_values = true)]
    theta0: Option<ThetaArg>,
    /// Seed of the reachable-minimum search.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Write the JSON report here ("-" for stdout).
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Args)]
struct CompensateArgs {
    /// The drive: a canonical CSV or a drive manifest (.toml).
    drive: PathBuf,
    /// θ as c_e,c_d,t_r,d (SI), or a parameter file (.yaml, .yml, .json).
    #[arg(long, allow_hyphen_values = true)]
    theta: ThetaArg,
    /// Output CSV (the drive plus n_rl_comp, n_rr_comp, compensated columns).
    #[arg(long)]
    out: PathBuf,
    /// QP solver: structured or clarabel.
    #[arg(long, default_value = "structured")]
    qp_solver: SolverKind,
    /// Segment length, samples (the drive is cut into consecutive segments).
    #[arg(long, default_value_t = 650)]
    segment_length: usize,
}

#[derive(Args)]
struct DemoArgs {
    /// Simulation seed (`--seed` seeds the calibration's random batches).
    #[arg(long, default_value_t = 1)]
    sim_seed: u64,
    /// Route length, km.
    #[arg(long, default_value_t = 24.0)]
    length_km: f64,
    /// Noise preset: paper, off, white or high.
    #[arg(long, default_value = "paper")]
    noise: String,
    /// Also write the simulated drive here.
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    calibration: CalibrationArgs,
    /// Write the JSON report here ("-" for stdout).
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Arguments of `odocal experiment`.
#[derive(Args)]
struct ExperimentArgs {
    /// Seed of the simulation and of the random batches.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulated route length, km.
    #[arg(long, default_value_t = 24.0)]
    pub length_km: f64,
    /// Noise preset of the simulation: paper, off, white (wheel white noise only) or high.
    #[arg(long, default_value = "paper")]
    pub noise: String,
    /// Run on this drive (canonical CSV) instead of simulating one; the truth
    /// is taken from its sidecar JSON when there is one.
    #[arg(long)]
    pub drive: Option<PathBuf>,
    /// QP solver for input compensation: structured or clarabel.
    #[arg(long, default_value = "structured")]
    pub qp_solver: SolverKind,
    /// Step 1: number of random batches of N = 10 segments.
    #[arg(long, default_value_t = 50)]
    pub batches: usize,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
}

/// Exit code of `calibrate` when the verdict is `rejected`.
const EXIT_REJECTED: u8 = 3;

/// How a successful command ends.
enum Outcome {
    /// Exit code 0.
    Done,
    /// The calibration was rejected: exit code [`EXIT_REJECTED`].
    Rejected,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(Outcome::Done) => ExitCode::SUCCESS,
        Ok(Outcome::Rejected) => ExitCode::from(EXIT_REJECTED),
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, leaving out a cause whose text the
/// line already holds (the library's I/O errors name the OS error once).
fn one_line(e: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line.replace('\n', " ")
}

fn run(cli: Cli) -> Result<Outcome> {
    let bars = progress::Bars::new(cli.quiet);
    let done = |r: Result<()>| r.map(|()| Outcome::Done);
    match cli.command {
        Command::Simulate(a) => done(simulate_cmd(a, &bars)),
        Command::Calibrate(a) => calibrate_cmd(a, &bars),
        Command::Validate(a) => done(validate_cmd(a, &bars)),
        Command::Compensate(a) => done(compensate_cmd(a, &bars)),
        // The demo shows a calibration; it is not one to deploy.
        Command::Demo(a) => demo_cmd(a, &bars).map(|_| Outcome::Done),
        Command::Experiment(a) => done(experiment::run(a, &bars)),
        Command::Import(a) => done(import_cmd(a)),
        Command::Inspect(a) => done(inspect::run(a)),
    }
}

/// Reads a drive: a canonical CSV, or a `.toml` manifest of a multi-stream log
/// (its import summary goes to stderr).
fn load_drive(path: &Path) -> Result<Drive> {
    Ok(load_drive_with_scale(path)?.0)
}

/// [`load_drive`], also returning how to read c_e when the drive came from a
/// manifest (e.g. "c_e is metres per 40360 ticks") and the manifest's
/// calibration settings (`[noise]`, `[reference]`).
fn load_drive_with_scale(path: &Path) -> Result<(Drive, Option<String>, Option<ManifestSettings>)> {
    let (drive, report) = odocal::load_drive(path)?;
    let settings = report.as_ref().map(ManifestSettings::of_report).transpose()?;
    if report.is_some() {
        eprintln!(
            "imported {}: {} samples in {} part(s), {:.2} km (run `odocal import` for the full import report)",
            path.display(),
            drive.len(),
            drive.parts().len(),
            drive.distance_m() / 1e3
        );
    }
    Ok((drive, report.map(|r| r.wheel_scale), settings))
}

/// θ on the command line: `c_e,c_d,t_r,d` (SI units), or the path of a
/// parameter file odocal wrote (`--params-out`: `.yaml`, `.yml`, `.json`).
#[derive(Debug, Clone)]
struct ThetaArg {
    theta: Theta,
    /// The parameter file θ came from, when it did.
    file: Option<(PathBuf, odocal::io::param_file::ParamFile)>,
}

impl std::str::FromStr for ThetaArg {
    type Err = odocal::Error;
    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        let path = Path::new(s);
        if odocal::io::param_file::is_param_file(path) {
            // `read` has checked θ (`theta()` cannot fail after it).
            let f = odocal::io::param_file::ParamFile::read(path)?;
            return Ok(ThetaArg { theta: f.theta()?, file: Some((path.into(), f)) });
        }
        Ok(ThetaArg { theta: s.parse()?, file: None })
    }
}

fn import_cmd(a: ImportArgs) -> Result<()> {
    let m = odocal::Manifest::from_path(&a.manifest)?;
    // The calibration settings are checked too, so a bad one is named now.
    ManifestSettings::of_manifest(&m)?;
    let imported = odocal::import(&m)?;
    imported.drive.write_csv(&a.out)?;
    if let Some(p) = &a.json {
        write_json(p, odocal::calibrate::settings::import_report_json(&imported.report)?)?;
        if p == Path::new("-") {
            return Ok(());
        }
    }
    println!("{}", imported.report.to_string().trim_end());
    println!("wrote {}", a.out.display());
    Ok(())
}

/// The simulator's sidecar beside a drive, when there is one.
fn load_truth(drive_path: &Path) -> Option<SimSidecar> {
    let p = sim::sidecar_path(drive_path);
    p.exists().then(|| SimSidecar::read_json(&p).ok()).flatten()
}

/// Writes a JSON report with its `schema_version` ("-": stdout).
fn write_json(path: &Path, mut value: serde_json::Value) -> Result<()> {
    if let Some(obj) = value.as_object_mut() {
        obj.insert("schema_version".into(), odocal::REPORT_SCHEMA_VERSION.into());
    }
    let text = serde_json::to_string_pretty(&value)?;
    if path == Path::new("-") {
        println!("{text}");
    } else {
        std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn sim_options(seed: u64, length_km: f64, noise: &str) -> Result<SimOptions> {
    let noise = NoiseOptions::by_name(noise)?;
    Ok(SimOptions { seed, length_km, noise, ..SimOptions::paper(seed) })
}

fn simulate_cmd(a: SimulateArgs, bars: &progress::Bars) -> Result<()> {
    let mut o = sim_options(a.seed, a.length_km, &a.noise)?;
    if let Some(t) = &a.theta {
        o.theta_true = t.theta;
    }
    if let Some(s) = a.substeps {
        o.substeps = s;
    }
    bars.stage("simulating");
    let out = sim::simulate(&o)?;
    bars.finish();
    out.drive.write_csv(&a.out)?;
    let side = sim::sidecar_path(&a.out);
    out.sidecar.write_json(&side)?;
    let s = &out.sidecar.stats;
    println!(
        "wrote {} ({} samples, {:.2} km, {:.0} s, max yaw rate {:.2} rad/s, max |a_y| {:.2} m/s², wheel error {:.2} % rms) and {}",
        a.out.display(),
        s.samples,
        s.distance_m / 1e3,
        s.duration_s,
        s.max_yaw_rate_rad_per_s,
        s.max_abs_lateral_acceleration_m_per_s2,
        s.wheel_rotation_rel_error_rms * 100.0,
        side.display()
    );
    Ok(())
}

/// Warnings to stderr, grouped by kind: at most [`WARNINGS_PER_KIND`] of
/// each and a count of the rest (the JSON report lists all).
fn print_warnings(warnings: &[Warning]) {
    let lines = odocal::assess::warning::summarize(warnings, WARNINGS_PER_KIND);
    let collapsed = lines.iter().any(|l| l.starts_with('…'));
    for l in lines {
        eprintln!("warning: {l}");
    }
    if collapsed {
        eprintln!("warning: (the --json report lists every warning)");
    }
}

/// Warnings of one kind printed before the rest are counted.
const WARNINGS_PER_KIND: usize = 3;

fn report_json(
    r: &CalibrationReport,
    truth: Option<(&Theta, f64)>,
    wheel_scale: Option<&str>,
) -> Result<serde_json::Value> {
    let mut v = serde_json::to_value(r)?;
    // The σ that stands for the result (the verdict's, --params-out's).
    if let Some(obj) = v.as_object_mut() {
        obj.insert("sigma".into(), serde_json::to_value(r.result_sigma())?);
    }
    // The `method` of the report (SPEC §9) is the name; its settings are in `options.method`.
    if let (Some((t, e)), Some(obj)) = (truth, v.as_object_mut()) {
        obj.insert("truth".into(), serde_json::json!({"theta": t, "mean_position_error_m": e}));
    }
    if let (Some(w), Some(obj)) = (wheel_scale, v.as_object_mut()) {
        obj.insert("wheel_scale".into(), serde_json::json!(w));
    }
    Ok(v)
}

/// The command line that calibrates c_e alone on `path`, with the user's
/// other settings, for the error when c_d, t_r, d are not observable.
fn c_e_only_command(path: &Path, args: &CalibrationArgs) -> String {
    let mut cmd = format!("odocal calibrate {} --method {}", path.display(), args.method);
    if let Some(h) = args.holdout {
        cmd.push_str(match h {
            HalfArg::FirstHalf => " --holdout first-half",
            HalfArg::SecondHalf => " --holdout second-half",
        });
    }
    cmd.push_str(" --fix c_d,t_r,d --min-yaw-rate 0");
    cmd
}

fn run_calibration(
    drive: &Drive,
    source: Option<(&Path, Option<&str>)>,
    manifest: Option<&ManifestSettings>,
    args: &CalibrationArgs,
    json: Option<&Path>,
    truth_theta: Option<Theta>,
    bars: &progress::Bars,
) -> Result<Outcome> {
    let (opts, setting_uses) = args.options(manifest)?;
    let noise_origin = settings::noise_origin(args, &setting_uses);
    let cb = |e| bars.event(e);
    let mut others = Vec::new();
    let mut other_settings = Vec::new();
    for p in &args.validate_on {
        let (d, _, m) = load_drive_with_scale(p).with_context(|| format!("--validate-on {}", p.display()))?;
        others.push((p.display().to_string(), d));
        other_settings.push(m);
    }
    let holdout = match args.holdout {
        Some(HalfArg::FirstHalf) => Some(Holdout::FirstHalf),
        Some(HalfArg::SecondHalf) => Some(Holdout::SecondHalf),
        None if others.is_empty() => None,
        None => {
            let refs: Vec<&Drive> = others.iter().map(|(_, d)| d).collect();
            Some(Holdout::Other(Drive::concat(&refs).context("--validate-on")?))
        }
    };
    // The halves are copies only when a hold-out is asked for.
    let split = holdout.as_ref().map(|h| h.split(drive)).transpose()?;
    let (fit, held) = match &split {
        Some((fit, held)) => (fit.as_ref(), Some(held.as_ref())),
        None => (drive, None),
    };
    // Each validation drive with the extrinsics that apply to it (its own
    // manifest's `[reference]` where the calibration neither estimates nor
    // is given them: odocal::assess::validation_drives).
    let validation: Vec<odocal::ValidationDrive> = others
        .iter()
        .zip(&other_settings)
        .map(|((name, d), m)| odocal::ValidationDrive {
            name,
            drive: d,
            reference: m.as_ref().and_then(|m| m.reference.as_ref()),
        })
        .collect();
    let given = settings::given_extrinsics(args);
    let result = match validation.is_empty() {
        true => odocal::calibrate_held_out(fit, held, &opts, Some(&cb)).map(|r| (r, None)),
        false => odocal::calibrate_validated_on(drive, &validation, given, &opts, Some(&cb)).map(|(r, m)| (r, Some(m))),
    };
    let (r, per_drive) = match result {
        Ok(r) => r,
        Err(e @ odocal::Error::NotObservable { .. }) => {
            bars.finish();
            let hint = match source {
                Some((p, _)) => format!("; run: {} (or add --auto-fix)", c_e_only_command(p, args)),
                None => "; or add --auto-fix".into(),
            };
            bail!("{e}{hint}");
        }
        Err(e) => return Err(e.into()),
    };
    let wheel_scale = source.and_then(|(_, w)| w);
    let drive = held.unwrap_or(drive);
    bars.finish();
    let truth = match truth_theta {
        Some(t) => {
            let val = segment::validation_segments(drive, &opts.validation)?;
            Some((t, odocal::mean_position_error(drive, &val, &t)?.mean_position_error_m))
        }
        None => None,
    };
    let truth_ref = truth.as_ref().map(|(t, e)| (t, *e));
    let input = source.map(|(p, _)| p.display().to_string()).unwrap_or_else(|| "simulated drive".into());
    if let Some(p) = &args.params_out {
        // The σ that stands for the result (the verdict's, the JSON's `sigma`).
        let mut f = r.param_file(&input);
        f.node = args.params_node.clone();
        f.mapping = args.params_mapping;
        f.write(p)?;
    }
    if let Some(p) = &args.report {
        let val = segment::validation_segments(drive, &opts.validation)?;
        let batches = r
            .initial_step()
            .map(|s| s.batches.iter().map(|b| (b.score.theta, b.score.mean_position_error_m)).collect())
            .unwrap_or_default();
        let html = odocal_report::ReportInput {
            provenance: vec![
                ("method".into(), r.method.clone()),
                ("input".into(), input.clone()),
                ("odocal".into(), env!("CARGO_PKG_VERSION").into()),
                ("date".into(), odocal::io::param_file::utc_date_today()),
            ],
            params: {
                let mut rows = odocal_report::ParamRow::theta_rows(
                    &r.initial.theta,
                    &r.theta,
                    Some(r.result_sigma().to_array()),
                    truth_ref.map(|t| t.0),
                );
                rows.extend(r.extrinsics.as_ref().map(odocal_report::ParamRow::extrinsics_rows).unwrap_or_default());
                rows
            },
            truth: truth_ref.map(|t| *t.0),
            verdict: Some((r.verdict.level.to_string(), r.verdict.reasons.iter().map(|x| x.to_string()).collect())),
            batches,
            warnings: r.warnings.iter().map(|w| w.to_string()).collect(),
            method_details: r.method_details().lines().map(str::to_string).collect(),
            ..odocal_report::ReportInput::new(input.clone(), drive, &val, r.initial.theta, r.theta)
        };
        odocal_report::write_html(p, &html)?;
    }
    let outcome = if r.verdict.level == VerdictLevel::Rejected { Outcome::Rejected } else { Outcome::Done };
    if let Some(p) = json {
        let mut v = report_json(&r, truth_ref, wheel_scale)?;
        if let (Some(m), Some(obj)) = (&per_drive, v.as_object_mut()) {
            obj.insert("validate_on".into(), serde_json::to_value(m)?);
        }
        settings::add_to_json(&mut v, &setting_uses, noise_origin.as_deref())?;
        write_json(p, v)?;
        if p == Path::new("-") {
            print_warnings(&r.warnings);
            return Ok(outcome);
        }
    }
    // The heading first, then the warnings (stderr), then the report.
    let text = report::calibration(&r, truth_ref, wheel_scale);
    let (head, rest) = text.split_once('\n').unwrap_or((&text, ""));
    println!("{head}");
    std::io::stdout().flush()?;
    print_warnings(&r.warnings);
    print!("{rest}");
    if let Some(m) = &per_drive {
        print!("{}", report::validate_on(m));
    }
    print!("{}", settings::report(&setting_uses, noise_origin.as_deref()));
    std::io::stdout().flush()?;
    Ok(outcome)
}

fn calibrate_cmd(a: CalibrateArgs, bars: &progress::Bars) -> Result<Outcome> {
    let mut drives = Vec::with_capacity(a.drive.len());
    let mut wheel_scale = None;
    let mut manifests = Vec::new();
    for p in &a.drive {
        let (d, w, m) = load_drive_with_scale(p)?;
        wheel_scale = wheel_scale.or(w);
        manifests.extend(m);
        drives.push(d);
    }
    let manifest = ManifestSettings::merge(&manifests)?;
    let first = &a.drive[0];
    let (drive, truth) = if drives.len() == 1 {
        (drives.swap_remove(0), load_truth(first).map(|s| s.theta_true))
    } else {
        let refs: Vec<&Drive> = drives.iter().collect();
        (Drive::concat(&refs).context("calibrating several drives jointly")?, None)
    };
    let source = Some((first.as_path(), wheel_scale.as_deref()));
    run_calibration(&drive, source, manifest.as_ref(), &a.calibration, a.json.as_deref(), truth, bars)
}

fn demo_cmd(a: DemoArgs, bars: &progress::Bars) -> Result<Outcome> {
    let o = sim_options(a.sim_seed, a.length_km, &a.noise)?;
    bars.stage("simulating");
    let sim = sim::simulate(&o)?;
    bars.finish();
    if let Some(p) = &a.out {
        sim.drive.write_csv(p)?;
        sim.sidecar.write_json(&sim::sidecar_path(p))?;
    }
    if a.json.as_deref() != Some(Path::new("-")) {
        let s = &sim.sidecar.stats;
        println!(
            "simulated {:.1} km, {:.0} s, seed {}, noise '{}' ({:.2} % rms wheel error); true θ: {}\n",
            s.distance_m / 1e3,
            s.duration_s,
            a.sim_seed,
            a.noise,
            s.wheel_rotation_rel_error_rms * 100.0,
            sim.sidecar.theta_true
        );
    }
    run_calibration(&sim.drive, None, None, &a.calibration, a.json.as_deref(), Some(sim.sidecar.theta_true), bars)
}

fn validate_cmd(a: ValidateArgs, bars: &progress::Bars) -> Result<()> {
    let (drive, _, settings) = load_drive_with_scale(&a.drive)?;
    let mut opts = odocal::ValidateOptions::default();
    // A manifest's [reference]: the drive's own mount.
    let stated = settings.as_ref().and_then(|s| s.reference.as_ref()).map(|r| r.extrinsics());
    if let Some(x) = stated {
        opts.extrinsics = x;
    }
    // A parameter file's extrinsics, as `--validate-on` takes a calibration's.
    let mut extrinsics_from = "the drive's manifest [reference]".to_string();
    if let Some((path, f)) = &a.theta.file {
        let (x, from_file) = f.extrinsics_for_drive(stated.as_ref());
        opts.extrinsics = x;
        extrinsics_from = if from_file.len() == 3 {
            path.display().to_string()
        } else if from_file.is_empty() {
            extrinsics_from
        } else {
            format!("{} from {}, the rest from the drive's manifest [reference]", from_file.join(", "), path.display())
        };
    }
    if let Some(v) = a.validation_length {
        opts.segments.length_steps = v;
        opts.segments.stride_steps = (v / 2).max(1);
    }
    if a.reachable_minimum {
        let centre = a.theta0.as_ref().map_or(Theta::PAPER_INITIAL, |t| t.theta);
        opts.reachable = Some(odocal::ReachableOptions {
            seed: a.seed,
            starts: vec![a.theta.theta],
            ..odocal::ReachableOptions::around(&centre)
        });
    }
    let cb = |e| bars.event(e);
    let report = odocal::validate_with_progress(&drive, &a.theta.theta, &opts, Some(&cb))?;
    bars.finish();
    if let Some(p) = &a.json {
        write_json(p, serde_json::to_value(&report)?)?;
        if p == Path::new("-") {
            return Ok(());
        }
    }
    let r = &report.validation;
    match &a.theta.file {
        Some((path, f)) => println!(
            "θ: {} (from {}{})",
            a.theta.theta,
            path.display(),
            f.verdict.as_ref().map(|v| format!(", verdict {v}")).unwrap_or_default()
        ),
        None => println!("θ: {}", a.theta.theta),
    }
    if !report.extrinsics.is_zero() {
        println!("reference extrinsics: {} ({extrinsics_from})", report.extrinsics);
    }
    println!("mean position error Ē_p: {:.4} m over {} validation segments", r.mean_position_error_m, r.segments);
    if let Some(rm) = &report.reachable_minimum {
        println!(
            "reachable minimum: Ē_p {:.4} m at θ = {} ({} evaluations, {:.1} s)",
            rm.mean_position_error_m, rm.theta, rm.evaluations, rm.time_s
        );
        if !report.extrinsics.is_zero() {
            println!("  (the search, too, takes the reference at the extrinsics above)");
        }
        if rm.recentred > 0 {
            println!("  the search box was re-centred {} time(s) on a best point at its edge", rm.recentred);
        }
        if !rm.enclosed {
            println!(
                "  NOT ENCLOSED: {} ended on the edge of the search box; the minimum may lie beyond \
                 (widen the box with --theta0 nearer the best point)",
                rm.at_edge
            );
        }
    }
    Ok(())
}

fn compensate_cmd(a: CompensateArgs, bars: &progress::Bars) -> Result<()> {
    let drive = load_drive(&a.drive)?;
    if a.segment_length < 2 {
        bail!("--segment-length must be at least 2");
    }
    let segs = segment::cut(&drive, 0, a.segment_length, a.segment_length);
    if segs.is_empty() {
        bail!("{}: too short for one segment of {} steps", a.drive.display(), a.segment_length);
    }
    let cb = |e| bars.event(e);
    let comp = odocal::compensate::compensate_segments(
        &drive,
        &segs,
        &[a.theta.theta],
        &odocal::CompensateOptions::default(),
        &QpOptions { solver: a.qp_solver, ..Default::default() },
        Some(&cb),
    )?;
    bars.finish();
    print_warnings(&comp.warnings.iter().cloned().map(odocal::Warning::from).collect::<Vec<_>>());
    let (mut c_rl, mut c_rr, mut flag) = (drive.n_rl().to_vec(), drive.n_rr().to_vec(), vec![0.0; drive.len()]);
    for (i, s) in comp.segments.iter().enumerate() {
        c_rl[s.start..s.start + s.steps].copy_from_slice(&comp.n_rl[i]);
        c_rr[s.start..s.start + s.steps].copy_from_slice(&comp.n_rr[i]);
        flag[s.start..s.start + s.steps].fill(1.0);
    }
    let drive = drive
        .with_extra(ExtraColumn::numbers("n_rl_comp", c_rl))?
        .with_extra(ExtraColumn::numbers("n_rr_comp", c_rr))?
        .with_extra(ExtraColumn::numbers("compensated", flag))?;
    drive.write_csv(&a.out)?;
    println!(
        "wrote {}: {} of {} segments compensated ({} QP solves, rms input change {:.3} %)",
        a.out.display(),
        comp.step.segments,
        segs.len(),
        comp.step.qp_solves,
        comp.step.rms_relative_input_change * 100.0
    );
    Ok(())
}

/// `--correct-bias B`: an even number of replicates, at least 2 (the
/// bootstrap's replicates come in antithetic pairs).
fn parse_even_replicates(s: &str) -> std::result::Result<usize, String> {
    let b: usize = s.parse().map_err(|e| format!("{e}"))?;
    if b < 2 || !b.is_multiple_of(2) {
        return Err(format!(
            "B must be an even number of at least 2 (the replicates come in antithetic pairs), got {b}"
        ));
    }
    Ok(b)
}
