//! The calibration options that `calibrate` and `demo` share, and the
//! argument types the subcommands have in common.
//!
//! `--help` lists the options most runs need; `--help-all` adds the expert
//! ones, grouped under headings, with their full explanations.

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use clap::{ArgAction, Args};
use odocal::compensate::SolverKind;
use odocal::settings::{Caller, NoiseModelSetting, Settings};
use odocal::{FinalSegments, Method, ParamSet, Theta};

/// Help heading of the segment and Gauss-Newton options.
const SEGMENTS: &str = "Segments and Gauss-Newton";
/// Help heading of the pose reference's extrinsics.
const EXTRINSICS: &str = "Reference extrinsics";
/// Help heading of the three-step method's options.
const THREE_STEP: &str = "Three-step method (--method three-step)";
/// Help heading of the EIV noise model's options.
const EIV_NOISE: &str = "EIV noise model (--method eiv)";
/// Help heading of the EIV bias correction and bootstrap.
const EIV_BIAS: &str = "EIV bias correction and bootstrap (--method eiv)";
/// Help heading of the parameter file's keys.
const PARAM_FILE: &str = "Parameter file (--params-out)";

/// `-h`/`--help` (the common options) and `--help-all` (every option): a
/// subcommand that flattens these sets `disable_help_flag`.
#[derive(Args, Clone)]
pub struct HelpArgs {
    /// Print the common options.
    #[arg(short, long, action = ArgAction::HelpShort, display_order = 1001)]
    help: Option<bool>,
    /// Print every option, with explanations.
    #[arg(long, action = ArgAction::HelpLong, display_order = 1002)]
    help_all: Option<bool>,
}

/// The options of a calibration (`calibrate`, `demo`): the library's
/// calibration settings ([`CalibrationArgs::settings`]) and the reports to
/// write.
#[derive(Args, Clone)]
pub struct CalibrationArgs {
    /// three-step, batch-gn or eiv (default).
    ///
    /// The calibration method. eiv (the default): an errors-in-variables filter over the whole drive,
    /// started from batch-gn on all segments; it falls back to that batch-gn
    /// when its consistency checks fail. three-step: the paper's method
    /// (random batches, input compensation by a QP, a final fit). batch-gn:
    /// one Gauss-Newton fit over the selected segments.
    #[arg(long)]
    pub method: Option<Method>,
    /// θ_0: c_e,c_d,t_r,d (SI) or a parameter file.
    ///
    /// The initial guess. In SI units: c_d in m, d in m per m/s². A parameter file is one that
    /// --params-out wrote (.yaml, .yml, .json), e.g. the last calibration's:
    /// its θ is taken.
    #[arg(long, allow_hyphen_values = true)]
    pub theta0: Option<ThetaArg>,
    /// The node of the --theta0 parameter file to read.
    ///
    /// A ROS 2 parameter file may hold several nodes' parameters (or several
    /// YAML documents); when more than one holds odocal's, name the node.
    #[arg(long)]
    pub theta0_node: Option<String>,
    /// Parameters held at θ_0 (e.g. c_d,t_r,d).
    ///
    /// Comma separated: c_e, c_d, t_r, d (and lever_x, lever_y,
    /// heading_offset when --estimate frees them).
    #[arg(long)]
    pub fix: Option<ParamSet>,
    /// Validate on one half: first-half, second-half.
    ///
    /// The drive is halved by time; the half named is held out for the
    /// validation and the calibration uses the other.
    #[arg(long, hide_possible_values = true)]
    pub holdout: Option<HalfArg>,
    /// Validate on other drives (comma separated).
    ///
    /// Drive CSVs or manifests of the same vehicle (repeat the flag or separate with commas)
    /// instead of the calibration drive: Ē_p per drive and over all of them.
    #[arg(long, conflicts_with = "holdout", value_delimiter = ',')]
    pub validate_on: Vec<PathBuf>,
    /// Carry the estimated heading offset to the --validate-on drives.
    ///
    /// By default each validation drive's own heading offset is
    /// re-estimated with θ and the lever arm held: it is the reference's
    /// heading bias as much as a mount angle, and it changes from drive to drive.
    #[arg(long, requires = "validate_on")]
    pub carry_heading_offset: bool,
    /// Hold what the data cannot determine at θ_0.
    ///
    /// The parameters the observability check names as not determined by
    /// the data (at θ_0, or in the fit: then it runs again with them
    /// held) are held instead of estimated. With no turning segment, c_d,
    /// t_r, d are held and every segment is used.
    #[arg(long)]
    pub auto_fix: bool,
    /// Write θ and 1σ to a ROS 2 .yaml or a .json ("-": YAML to stdout).
    ///
    /// The calibrated parameters with their 1σ, units, verdict and
    /// provenance (with the drives' fingerprints): a ROS 2 parameter file
    /// (.yaml/.yml) or JSON (.json); "-" writes the YAML to stdout instead of
    /// the text report. `--theta0` and `validate --theta` read it back.
    #[arg(long, value_parser = params_out_path)]
    pub params_out: Option<PathBuf>,
    /// Write a self-contained HTML report here ("-": stdout).
    ///
    /// The verdict, θ, a map, per-segment errors, residuals and warnings, in
    /// one file without scripts or network fetches; "-" writes it to stdout
    /// instead of the text report.
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Minimum peak yaw rate for a segment to be selected, rad/s (0: every
    /// segment). Three-step and batch-gn (eiv fits every segment).
    #[arg(long, help_heading = SEGMENTS, hide_short_help = true, value_parser = yaw_rate)]
    pub min_yaw_rate: Option<f64>,
    /// Keep the paper's turning-only segment selection even when every
    /// selected segment turns the same way (default: the straight segments
    /// are added, with a warning, because one-way turns confound c_d with
    /// t_r). Three-step and batch-gn; wins over a manifest's
    /// `[calibration] keep_one_way`.
    #[arg(long, help_heading = SEGMENTS, hide_short_help = true)]
    pub keep_one_way: bool,
    /// Calibration segment length K, samples.
    #[arg(long, help_heading = SEGMENTS, hide_short_help = true, value_parser = samples_at_least::<2>)]
    pub segment_length: Option<usize>,
    /// Calibration segment stride, samples.
    #[arg(long, help_heading = SEGMENTS, hide_short_help = true, value_parser = samples_at_least::<1>)]
    pub segment_stride: Option<usize>,
    /// Validation segment length K_v, samples.
    #[arg(long, help_heading = SEGMENTS, hide_short_help = true, value_parser = samples_at_least::<2>)]
    pub validation_length: Option<usize>,
    /// Maximum Gauss-Newton iterations.
    #[arg(long, help_heading = SEGMENTS, hide_short_help = true, value_parser = whole::<usize>)]
    pub max_iterations: Option<usize>,
    /// Also estimate the pose reference's extrinsics with θ: lever-arm
    /// and/or heading-offset (or lever_x, lever_y, heading_offset). The
    /// validation then compares the model's reference point with the
    /// reference. Batch-gn, three-step (its first and final fits) and eiv
    /// (two-stage: its batch G-N start estimates them, the filter holds them).
    #[arg(long, help_heading = EXTRINSICS, hide_short_help = true)]
    pub estimate: Option<ParamSet>,
    /// Lever arm X,Y (m, x forward, y left) of the pose reference from the
    /// rear-axle centre: held at this value, or the start of --estimate. Default 0,0.
    #[arg(long, allow_hyphen_values = true, help_heading = EXTRINSICS, hide_short_help = true,
          value_parser = lever_arm_text)]
    pub lever_arm: Option<String>,
    /// Heading offset (rad) of the pose reference (reference heading minus
    /// vehicle heading): held, or the start of --estimate. Default 0.
    #[arg(long, allow_hyphen_values = true, help_heading = EXTRINSICS, hide_short_help = true)]
    pub heading_offset: Option<f64>,
    /// Seed of the random batches and of the final fit's random segments [default: 0].
    #[arg(long, help_heading = THREE_STEP, hide_short_help = true, value_parser = whole::<u64>)]
    pub seed: Option<u64>,
    /// QP solver for input compensation, structured (default) or clarabel.
    #[arg(long, help_heading = THREE_STEP, hide_short_help = true)]
    pub qp_solver: Option<SolverKind>,
    /// Number of random batches of the first fit.
    #[arg(long, help_heading = THREE_STEP, hide_short_help = true, value_parser = whole::<usize>)]
    pub batches: Option<usize>,
    /// Segments per batch of the first fit.
    #[arg(long, help_heading = THREE_STEP, hide_short_help = true, value_parser = whole::<usize>)]
    pub batch_size: Option<usize>,
    /// Number of batch estimates θ_B,I picked to start the compensation from.
    #[arg(long, help_heading = THREE_STEP, hide_short_help = true, value_parser = whole::<usize>)]
    pub picks: Option<usize>,
    /// Segments of the final fit: "all" selected segments or a number of random ones.
    #[arg(long, help_heading = THREE_STEP, hide_short_help = true)]
    pub final_segments: Option<FinalSegments>,
    /// Starting noise model, a TOML file of noise-model fields (e.g.
    /// `wheel_white_rel_sigma = 0.01`; missing fields keep the production-car
    /// defaults; `known = ["heading_white"]` holds stated levels; see
    /// docs/reference.md).
    #[arg(long, help_heading = EIV_NOISE, hide_short_help = true)]
    pub noise_model: Option<PathBuf>,
    /// Noise sources whose level in the starting model is known (e.g. from
    /// the INS datasheet) and held, not estimated: wheel-white, wheel-common,
    /// wheel-differential, pose-white, pose-drift, heading-white (comma
    /// list; adds to a noise model's `known`).
    #[arg(long, value_delimiter = ',', help_heading = EIV_NOISE, hide_short_help = true)]
    pub known_noise: Vec<odocal::eiv::NoiseSource>,
    /// Use the starting noise model as is instead of estimating its scales.
    #[arg(long, help_heading = EIV_NOISE, hide_short_help = true)]
    pub fix_noise: bool,
    /// Keep the EIV result even when its consistency checks fail (default:
    /// fall back to batch G-N on all segments).
    #[arg(long, help_heading = EIV_NOISE, hide_short_help = true)]
    pub no_fallback: bool,
    /// Filter window length, samples.
    #[arg(long, help_heading = EIV_NOISE, hide_short_help = true, value_parser = whole::<usize>)]
    pub eiv_window: Option<usize>,
    /// How encoder quantisation enters the noise model: process (a white
    /// rate noise that accumulates), measurement (a pose noise) or counting
    /// (the exact counting error, two more filter states, about 1.2× the
    /// time). Default: the library's (`EivOptions::quantisation`).
    #[arg(long, value_name = "MODEL", help_heading = EIV_NOISE, hide_short_help = true,
          value_parser = library_enum::<odocal::eiv::QuantisationModel>(&["process", "measurement", "counting"]))]
    pub quantisation: Option<odocal::eiv::QuantisationModel>,
    /// The quantisation step q: scaled (estimated with the white wheel noise
    /// from the noise model's q), given (the noise model's q, held) or
    /// from-readings (read off the wheel readings when they lie on the
    /// lattice of counted ticks; readings on none carry no quantisation,
    /// q = 0). Default: the library's
    /// (`EivOptions::quantisation_level`).
    #[arg(long, value_name = "LEVEL", help_heading = EIV_NOISE, hide_short_help = true,
          value_parser = library_enum::<odocal::eiv::QuantisationLevel>(&["scaled", "given", "from-readings"]))]
    pub quantisation_level: Option<odocal::eiv::QuantisationLevel>,
    /// The a_y and β noise scaled with the white wheel noise (tied; a_y's σ
    /// never below the white noise of its own readings) or held at the noise
    /// model's σ (stated: the IMU's and the sideslip source's noise, e.g.
    /// from `--noise-model`). Default: the library's
    /// (`EivOptions::lateral_noise`).
    #[arg(long, value_name = "SCALE", help_heading = EIV_NOISE, hide_short_help = true,
          value_parser = library_enum::<odocal::eiv::LateralNoise>(&["tied", "stated"]))]
    pub lateral_noise: Option<odocal::eiv::LateralNoise>,
    /// The reference heading's white noise scaled together with the
    /// position noise (tied) or by a scale of its own (separate). Default:
    /// the library's (`EivOptions::heading_scale`).
    #[arg(long, value_name = "SCALE", help_heading = EIV_NOISE, hide_short_help = true,
          value_parser = library_enum::<odocal::eiv::HeadingScale>(&["tied", "separate"]))]
    pub heading_noise: Option<odocal::eiv::HeadingScale>,
    /// Parametric bootstrap with B replicates (re-simulate the fitted noise,
    /// re-fit B times): percentile intervals and the estimator's own bias in
    /// the report; about B extra fits of time.
    #[arg(long, value_name = "B", help_heading = EIV_BIAS, hide_short_help = true, value_parser = whole::<usize>)]
    pub bootstrap: Option<usize>,
    /// Seed of the bootstrap's replicates (--bootstrap, and the bias
    /// correction) [default: 0].
    #[arg(long, help_heading = EIV_BIAS, hide_short_help = true, value_parser = whole::<u64>)]
    pub bootstrap_seed: Option<u64>,
    /// Replicates B of the bias correction that is on by default (B = 4):
    /// the estimator's own bias, estimated by a parametric bootstrap of B
    /// re-simulations in antithetic pairs (B even; seed --bootstrap-seed)
    /// on the smoothed trajectory, each fitted by one scoring step from the
    /// estimate with the fitted noise model held, is subtracted from the
    /// parameters --correct-bias-of names; their σ includes its Monte Carlo
    /// error. It runs only for a fit that is kept.
    #[arg(long, value_name = "B", help_heading = EIV_BIAS, hide_short_help = true,
          value_parser = parse_even_replicates, conflicts_with = "no_bias_correction")]
    pub correct_bias: Option<usize>,
    /// The parameters of θ the bias correction corrects, comma-separated
    /// [default: c_e,c_d]. On simulated drives with random noise it takes
    /// c_e's error down 2.6-8.4 times, c_d's by a fifth under heavy
    /// common-mode wheel noise, and removes none of t_r's or d's; adding
    /// t_r helps where the wheel noise is white, as the fitted model's (the
    /// `high` preset: t_r +1.09 % → +0.36 %), and not otherwise
    /// (docs/validation.md).
    #[arg(long, value_name = "PARAMS", help_heading = EIV_BIAS, hide_short_help = true,
          conflicts_with = "no_bias_correction")]
    pub correct_bias_of: Option<ParamSet>,
    /// Return the profile cost's root as is, without the default bias
    /// correction (see --correct-bias).
    #[arg(long, help_heading = EIV_BIAS, hide_short_help = true)]
    pub no_bias_correction: bool,
    /// ROS node name of the parameter file.
    #[arg(long, default_value = "odocal", help_heading = PARAM_FILE, hide_short_help = true,
          value_parser = ros_node_name)]
    pub params_node: String,
    /// Also write the parameters under a consumer's keys: odocal (none) or
    /// diff_drive_controller (wheel_separation, wheel_radius, radius multipliers).
    #[arg(long, default_value = "odocal", help_heading = PARAM_FILE, hide_short_help = true)]
    pub params_mapping: odocal::ParamMapping,
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
pub enum HalfArg {
    FirstHalf,
    SecondHalf,
}

impl CalibrationArgs {
    /// The calibration settings the flags give (the library checks them
    /// and maps them to its options).
    pub fn settings(&self) -> Result<Settings> {
        let lever_arm = self.lever_arm.as_deref().map(parse_lever_arm).transpose()?;
        Ok(Settings {
            method: self.method.clone(),
            theta0: self.theta0.as_ref().map(|t| t.resolved(self.theta0_node.as_deref())).transpose()?.map(|t| t.theta),
            fix: self.fix,
            auto_fix: self.auto_fix.then_some(true),
            seed: self.seed,
            max_iterations: self.max_iterations,
            min_yaw_rate: self.min_yaw_rate,
            keep_one_way: self.keep_one_way.then_some(true),
            segment_length: self.segment_length,
            segment_stride: self.segment_stride,
            validation_length: self.validation_length,
            estimate: self.estimate,
            lever_arm,
            heading_offset: self.heading_offset,
            batches: self.batches,
            batch_size: self.batch_size,
            picks: self.picks,
            final_segments: self.final_segments,
            qp_solver: self.qp_solver,
            noise_model: self.noise_model.clone().map(NoiseModelSetting::File),
            known_noise: (!self.known_noise.is_empty()).then(|| self.known_noise.clone()),
            fix_noise: self.fix_noise.then_some(true),
            fallback: self.no_fallback.then_some(false),
            eiv_window: self.eiv_window,
            quantisation: self.quantisation,
            quantisation_level: self.quantisation_level,
            lateral_noise: self.lateral_noise,
            heading_noise: self.heading_noise,
            bootstrap: self.bootstrap,
            bootstrap_seed: self.bootstrap_seed,
            correct_bias: if self.no_bias_correction { Some(0) } else { self.correct_bias },
            correct_bias_of: self.correct_bias_of,
        })
    }
}

/// θ on the command line: `c_e,c_d,t_r,d` (SI units), or the path of a
/// parameter file odocal wrote (`--params-out`: `.yaml`, `.yml`, `.json`).
/// A file that holds several nodes' parameters waits for `--params-node`
/// ([`ThetaArg::resolved`]).
#[derive(Debug, Clone)]
pub struct ThetaArg {
    pub theta: Theta,
    /// The parameter file θ came from, when it did.
    pub file: Option<(PathBuf, odocal::ParamFile)>,
    /// A parameter file that needs a node named to be read, and why.
    pending: Option<(PathBuf, String)>,
}

impl std::str::FromStr for ThetaArg {
    type Err = odocal::Error;
    fn from_str(s: &str) -> std::result::Result<Self, Self::Err> {
        let path = Path::new(s);
        if odocal::ParamFile::is_param_file(path) {
            // `read` has checked θ (`theta()` cannot fail after it).
            return match odocal::ParamFile::read(path, None) {
                Ok(f) => Ok(ThetaArg { theta: Theta::try_from(&f)?, file: Some((path.into(), f)), pending: None }),
                Err(e) if e.to_string().contains("--params-node") => {
                    let nan = Theta { c_e: f64::NAN, c_d: f64::NAN, t_r: f64::NAN, d: f64::NAN };
                    Ok(ThetaArg { theta: nan, file: None, pending: Some((path.into(), e.to_string())) })
                }
                Err(e) => Err(e),
            };
        }
        // Four numbers, else (text naming an existing file) the settings'
        // reading of θ text says the file's name lacks a parameter file's extension.
        let theta = odocal::Theta::try_from(serde_json::Value::String(s.into()))?;
        Ok(ThetaArg { theta, file: None, pending: None })
    }
}

impl ThetaArg {
    /// The parameter file named, read or waiting for its node.
    pub fn path(&self) -> Option<&Path> {
        self.file.as_ref().map(|f| f.0.as_path()).or(self.pending.as_ref().map(|p| p.0.as_path()))
    }

    /// This θ with its parameter file read at the node `node`
    /// (`--params-node`); without one, a file holding several nodes'
    /// parameters is an error that says to name one.
    pub fn resolved(&self, node: Option<&str>) -> Result<ThetaArg> {
        match (self.path(), node) {
            (Some(path), Some(node)) => {
                let f = odocal::ParamFile::read(path, Some(node))
                    .map_err(|e| odocal::Error::InvalidFlags(e.to_string()))?;
                Ok(ThetaArg { theta: Theta::try_from(&f)?, file: Some((path.into(), f)), pending: None })
            }
            (None, Some(_)) => Err(odocal::Error::InvalidFlags(
                "--params-node names a node of a parameter file, but θ was given as numbers".into(),
            )
            .into()),
            // A usage error, as every other parameter file `--theta` cannot read.
            (_, None) => match &self.pending {
                Some((_, why)) => Err(odocal::Error::InvalidFlags(why.clone()).into()),
                None => Ok(self.clone()),
            },
        }
    }
}

/// A `--params-out` path: its extension names the format (`.yaml`,
/// `.yml`: a ROS 2 parameter file; `.json`), checked before any work; `-`
/// writes the YAML to stdout.
pub fn params_out_path(s: &str) -> std::result::Result<PathBuf, String> {
    let path = PathBuf::from(s);
    if crate::output::is_stdout(&path) || odocal::ParamFile::is_param_file(&path) {
        Ok(path)
    } else {
        Err("the file name says the format: end it in .yaml or .yml (a ROS 2 parameter file) or .json, or \
                  give - for the YAML on stdout"
            .into())
    }
}

/// `--lever-arm X,Y` checked when the command line is parsed (a usage error).
fn lever_arm_text(s: &str) -> std::result::Result<String, String> {
    parse_lever_arm(s).map(|_| s.to_string()).map_err(|e| e.to_string())
}

/// `--lever-arm X,Y`: two numbers, metres.
fn parse_lever_arm(s: &str) -> Result<[f64; 2]> {
    let v: Vec<&str> = s.split(',').map(str::trim).collect();
    let parsed: Vec<f64> = v.iter().filter_map(|x| x.parse::<f64>().ok()).collect();
    match parsed[..] {
        [x, y] if v.len() == 2 => Ok([x, y]),
        _ => bail!("--lever-arm takes X,Y in metres (x forward, y left), got '{s}'"),
    }
}

/// The counts `settings` states checked as `calibrate` checks its flags:
/// each at most its ceiling (and the three-step counts at least 1), a
/// usage error naming the flag (`--batches = 0: must be at least 1`).
pub fn check_counts(settings: Settings) -> Result<()> {
    settings.resolve(&[], Caller::CommandLine)?;
    Ok(())
}

/// True for a negative number (`-1`, `-0.5`): what a count cannot be.
fn negative(s: &str) -> bool {
    s.trim().strip_prefix('-').is_some_and(|r| r.parse::<f64>().is_ok_and(|v| v > 0.0))
}

/// `s` as a whole number: a negative one is the error `on_negative` gives,
/// another that does not parse the parser's reason.
fn parse_whole<T: std::str::FromStr<Err = std::num::ParseIntError>>(
    s: &str,
    on_negative: impl FnOnce() -> String,
) -> std::result::Result<T, String> {
    s.parse().map_err(|e| if negative(s) { on_negative() } else { format!("{e}") })
}

/// A count or a seed on the command line (a whole number, 0 or more): a
/// negative one is a usage error saying so, another that does not parse
/// gives the parser's reason.
pub fn whole<T: std::str::FromStr<Err = std::num::ParseIntError>>(s: &str) -> std::result::Result<T, String> {
    parse_whole(s, || format!("must be 0 or more, got {s}"))
}

/// A segment length (at least 2 samples: one step) or stride (at least 1)
/// on the command line: a smaller one is a usage error naming the option.
pub fn samples_at_least<const MIN: usize>(s: &str) -> std::result::Result<usize, String> {
    let n: usize = parse_whole(s, || format!("must be at least {MIN} samples, got {s}"))?;
    if n < MIN {
        return Err(format!("must be at least {MIN} samples, got {n}"));
    }
    Ok(n)
}

/// `--correct-bias B`: an even number of replicates, at least 2 (the
/// bootstrap's replicates come in antithetic pairs).
fn parse_even_replicates(s: &str) -> std::result::Result<usize, String> {
    let b: usize = parse_whole(s, || format!("B must be an even number of at least 2, got {s}"))?;
    if b < 2 || !b.is_multiple_of(2) {
        return Err(format!(
            "B must be an even number of at least 2 (the replicates come in antithetic pairs), got {b}"
        ));
    }
    Ok(b)
}

/// `--vehicle ID`, the key of the vehicle's rows in the history, checked
/// as the history checks every record ([`odocal_history::check_vehicle_id`]):
/// a usage error otherwise.
pub fn vehicle_id(s: &str) -> std::result::Result<String, String> {
    odocal_history::check_vehicle_id(s).map(|()| s.to_string()).map_err(reason)
}

/// `--params-node NAME`, the node a ROS 2 parameter file is written for,
/// checked as every parameter file's node is
/// ([`odocal::ParamFile::check_node_name`]): a usage error otherwise.
pub fn ros_node_name(s: &str) -> std::result::Result<String, String> {
    odocal::ParamFile::check_node_name(s).map(|()| s.to_string()).map_err(reason)
}

/// What is wrong with a flag's value, as clap prints it after the flag:
/// the library's reason without its `invalid option` prefix.
fn reason(e: odocal::Error) -> String {
    match e {
        odocal::Error::InvalidOption { reason, .. } => reason,
        e => e.to_string(),
    }
}

/// `--min-yaw-rate R`: a non-negative number of rad/s (0 selects every
/// segment), checked when the command line is parsed (a usage error).
pub fn yaw_rate(s: &str) -> std::result::Result<f64, String> {
    match s.parse::<f64>() {
        Ok(r) if r.is_finite() && r >= 0.0 => Ok(r),
        _ => Err(format!("'{s}' is not a non-negative number of rad/s (0 selects every segment)")),
    }
}
