//! The `odocal` command-line tool: a thin layer over the `odocal` library.
//!
//! Human-readable output goes to stdout, progress bars and warnings to
//! stderr; errors are one line on stderr and exit code 1 (2 for usage
//! errors). `calibrate` exits with [`EXIT_REJECTED`] when the verdict is
//! `rejected` (the report is still written).
//!
//! One module per subcommand (its arguments and its run function);
//! [`args`] holds the calibration options `calibrate` and `demo` share,
//! [`io`] the reading of drives and writing of reports.

use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

mod args;
mod calibrate;
mod compensate;
mod experiment;
mod import;
mod inspect;
mod io;
mod progress;
mod report;
mod settings;
mod simulate;
mod validate;

/// The line under `calibrate --help` and `demo --help` that names what
/// `--help-all` adds.
const MORE_OPTIONS: &str =
    "More options (--help-all): segments and Gauss-Newton, reference extrinsics, the three-step \
                            method, the EIV noise model, EIV bias correction and bootstrap, parameter-file keys.";

#[derive(Parser)]
#[command(
    name = "odocal",
    version,
    about = "Wheel-odometry model calibration with input compensation by optimal control",
    after_help = "`odocal COMMAND --help` for a command's options."
)]
struct Cli {
    /// No progress bars.
    #[arg(long, short, global = true, display_order = 1000)]
    quiet: bool,
    /// Worker threads (default: one per core).
    ///
    /// Worker threads of the parallel stages (default: one per core); the
    /// results do not depend on their number.
    #[arg(long, global = true, value_name = "N", display_order = 1000)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a drive with known true parameters: writes DRIVE.csv and its truth, DRIVE.json.
    Simulate(simulate::SimulateArgs),
    /// Calibrate θ from a drive CSV or a manifest (TOML); several drives are fitted jointly.
    #[command(
        disable_help_flag = true,
        after_help = MORE_OPTIONS,
        after_long_help = "A manifest's [calibration], [noise] and [reference] settings apply where no flag \
                           gives them.\nExit codes: 0 done, 1 error, 2 usage error, 3 calibration rejected (the \
                           reports are still written)."
    )]
    Calibrate(calibrate::CalibrateArgs),
    /// Mean position error Ē_p of a θ (c_e,c_d,t_r,d or a parameter file) on a drive CSV or manifest.
    Validate(validate::ValidateArgs),
    /// Compensate a drive's wheel rotations for a θ: writes them beside the measured ones.
    Compensate(compensate::CompensateArgs),
    /// Simulate a drive, calibrate it with calibrate's options and compare with the truth.
    #[command(
        disable_help_flag = true,
        after_help = MORE_OPTIONS,
        after_long_help = "The demo's calibration is not one to deploy: it exits with 0 whatever the verdict."
    )]
    Demo(calibrate::DemoArgs),
    /// Reproduce the paper's §6 on a simulated drive or a drive CSV: report.md, SVG figures, experiment.json.
    Experiment(experiment::ExperimentArgs),
    /// Import a multi-stream log described by a manifest (TOML) into a canonical drive CSV.
    Import(import::ImportArgs),
    /// List a ROS 2 bag's (MCAP) topics, rates and manifest columns, or draft its manifest.
    Inspect(inspect::InspectArgs),
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
    if let Some(n) = cli.threads {
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("--threads")?;
    }
    let bars = progress::Bars::new(cli.quiet);
    let done = |r: Result<()>| r.map(|()| Outcome::Done);
    match cli.command {
        Command::Simulate(a) => done(simulate::run(a, &bars)),
        Command::Calibrate(a) => calibrate::calibrate_cmd(a, &bars),
        Command::Validate(a) => done(validate::run(a, &bars)),
        Command::Compensate(a) => done(compensate::run(a, &bars)),
        // The demo shows a calibration; it is not one to deploy.
        Command::Demo(a) => calibrate::demo_cmd(a, &bars).map(|_| Outcome::Done),
        Command::Experiment(a) => done(experiment::run(a, &bars)),
        Command::Import(a) => done(import::run(a)),
        Command::Inspect(a) => done(inspect::run(a)),
    }
}
