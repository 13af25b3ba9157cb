//! The `odocal` command-line tool: a thin layer over the `odocal` library.
//!
//! Human-readable output goes to stdout, progress bars and warnings to
//! stderr; errors are one line on stderr and exit code 1 (2 for usage
//! errors). `calibrate` exits with [`EXIT_REJECTED`] when the verdict is
//! `rejected`, and `validate` when θ does not fit the drive (the report is
//! still written). Interrupted (Ctrl-C, SIGTERM,
//! SIGHUP), it removes the temporary file of an output being written and
//! exits with 130.
//!
//! One module per subcommand (its arguments and its run function);
//! [`args`] holds the calibration options `calibrate` and `demo` share,
//! [`io`] the reading of drives and writing of reports, [`output`] the
//! checks of output paths and the atomic writes.

use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

mod args;
mod calibrate;
mod compensate;
mod experiment;
mod follow;
mod history;
mod import;
mod inspect;
mod io;
mod output;
mod progress;
mod simulate;
mod validate;

/// The line under `calibrate --help` and `demo --help` that names what
/// `--help-all` adds.
const MORE_OPTIONS: &str = "More options (--help-all): segments, reference extrinsics, three-step, EIV noise \
                            model, EIV bias correction, parameter file.";

/// The line under `follow --help` that names what `--help-all` adds.
const FOLLOW_MORE_OPTIONS: &str =
    "More options (--help-all): the online calibrator's and the write-back gates' settings.";

/// The lines at the end of `calibrate --help-all`.
const CALIBRATE_NOTES: &str = "A manifest's [calibration], [noise] and [reference] settings apply where no flag \
                               gives them. The results do not depend on --threads.\n\
                               Exit codes: 0 done, 1 error, 2 usage error, 3 calibration rejected (the reports \
                               are still written).";

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
    #[arg(long, global = true, value_name = "N", display_order = 1000, value_parser = parse_threads)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Simulate a drive with known θ (writes DRIVE.csv and DRIVE.json).
    ///
    /// DRIVE.json, the sidecar, holds the true θ and the noise settings;
    /// `calibrate` and `experiment` compare with it.
    Simulate(simulate::SimulateArgs),
    /// Calibrate θ from a drive CSV or a manifest (TOML).
    ///
    /// Several drives of one vehicle are fitted jointly.
    #[command(
        disable_help_flag = true,
        after_help = MORE_OPTIONS,
        after_long_help = CALIBRATE_NOTES
    )]
    Calibrate(calibrate::CalibrateArgs),
    /// Validate a θ (c_e,c_d,t_r,d or a parameter file) on a drive: Ē_p and a verdict.
    ///
    /// The mean position error Ē_p of dead reckoning with θ on the validation
    /// segments of a drive CSV or manifest, and whether θ fits the drive:
    /// its Ē_p within 1.6 times that of θ fitted on the drive (batch G-N
    /// from θ and from θ_0, or the default method from θ_0 where batch G-N's
    /// fit is worse than θ or held what the drive does not determine);
    /// optionally the reachable minimum. Exit code 3 when θ does not fit (the
    /// report is still printed and written).
    Validate(validate::ValidateArgs),
    /// Write a drive's wheel rotations compensated for a θ beside them.
    ///
    /// The three-step method's input compensation (a QP per segment) for a
    /// given θ: the drive CSV gains n_rl_comp, n_rr_comp and compensated.
    Compensate(compensate::CompensateArgs),
    /// Simulate a drive, calibrate it and compare with the truth.
    ///
    /// The calibration takes calibrate's options except --db and --vehicle
    /// (the demo records no history). It is not one to deploy: the demo
    /// exits with 0 whatever the verdict.
    #[command(disable_help_flag = true, after_help = MORE_OPTIONS)]
    Demo(calibrate::DemoArgs),
    /// The paper's §6 on a drive: report.md, SVG figures, experiment.json.
    ///
    /// On a simulated drive, or on a drive CSV (with the truth from its
    /// sidecar when it has one).
    Experiment(experiment::ExperimentArgs),
    /// Import a log described by a manifest (TOML) into a drive CSV.
    ///
    /// The manifest names the streams (CSV, MCAP, Parquet) of a multi-stream
    /// log; the result is a canonical drive CSV.
    Import(import::ImportArgs),
    /// List a ROS 2 bag's (MCAP) topics; draft a manifest for it.
    ///
    /// Topics, types, counts and rates, and the manifest columns of each
    /// topic odocal reads; with --manifest, a draft manifest.
    Inspect(inspect::InspectArgs),
    /// Replay drives in time order as if live: online calibration with
    /// gated write-back.
    ///
    /// Each drive streams through the online calibrator (a recursive
    /// Gauss-Newton); at its end the write-back gates decide whether the
    /// estimate replaces the vehicle's stored parameters. Decisions and
    /// written updates go to the history database.
    #[command(disable_help_flag = true, after_help = FOLLOW_MORE_OPTIONS)]
    Follow(follow::FollowArgs),
    /// A vehicle's calibration history: rows, drift flags, pooled estimate.
    History(history::HistoryArgs),
}

/// Exit code of a bad command line (clap's for what it parses).
const EXIT_USAGE: u8 = 2;

/// Exit code of `calibrate` when the verdict is `rejected`, and of
/// `validate` when θ does not fit the drive.
const EXIT_REJECTED: u8 = 3;

/// How a successful command ends.
enum Outcome {
    /// Exit code 0.
    Done,
    /// The calibration was rejected, or θ does not fit the drive
    /// validated on: exit code [`EXIT_REJECTED`].
    Rejected,
}

/// Exit code after Ctrl-C (SIGINT) or SIGTERM: 128 + 2, as a shell reports it.
const EXIT_INTERRUPTED: i32 = 130;

/// Exit code when stdout is a closed pipe (`odocal inspect bag | head`):
/// 128 + SIGPIPE (13), as a shell reports a tool the signal ended.
const EXIT_BROKEN_PIPE: i32 = 141;

/// Ends the process quietly with [`EXIT_BROKEN_PIPE`] when printing fails
/// because the reader of stdout has gone (`println!` panics with "Broken
/// pipe"); any other panic is reported as usual.
fn quiet_on_closed_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let text = info
            .payload()
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| info.payload().downcast_ref::<&str>().copied())
            .unwrap_or("");
        if text.contains("Broken pipe") {
            odocal::output::remove_temporary_files();
            std::process::exit(EXIT_BROKEN_PIPE);
        }
        default(info);
    }));
}

fn main() -> ExitCode {
    // Interrupted, odocal leaves no temporary file of an output behind (the
    // final path keeps its previous file: odocal::output).
    let _ = ctrlc::set_handler(|| {
        odocal::output::remove_temporary_files();
        std::process::exit(EXIT_INTERRUPTED);
    });
    quiet_on_closed_pipe();
    let cli = Cli::from_arg_matches(&command().get_matches()).unwrap_or_else(|e| e.format(&mut command()).exit());
    match run(cli) {
        Ok(Outcome::Done) => ExitCode::SUCCESS,
        Ok(Outcome::Rejected) => ExitCode::from(EXIT_REJECTED),
        Err(e) if closed_pipe(&e) => {
            odocal::output::remove_temporary_files();
            ExitCode::from(EXIT_BROKEN_PIPE as u8)
        }
        Err(e) => {
            eprintln!("error: {}", one_line(&e));
            // Flags that cannot be used together or as given: a bad command line.
            if e.chain().any(|c| matches!(c.downcast_ref::<odocal::Error>(), Some(odocal::Error::InvalidFlags(_)))) {
                ExitCode::from(EXIT_USAGE)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}

/// The command line: [`Cli`] with every option that takes a value taking a
/// negative number as one (`--steady-s -1`), so a value out of its range
/// gets the option's own message (`must be …`), not clap's advice to pass
/// it after `--`.
fn command() -> clap::Command {
    negative_numbers(Cli::command())
}

/// `cmd` and its subcommands, each of their options that takes a value
/// set to take a negative number (`Arg::allow_negative_numbers`).
fn negative_numbers(cmd: clap::Command) -> clap::Command {
    cmd.mut_args(|a| if a.get_action().takes_values() { a.allow_negative_numbers(true) } else { a })
        .mut_subcommands(negative_numbers)
}

/// Whether writing failed because the reader of stdout has gone (an
/// `EPIPE` anywhere in the error's chain, the library's I/O errors and an
/// I/O error wrapped by the CSV writer included).
fn closed_pipe(e: &anyhow::Error) -> bool {
    let broken = |io: &std::io::Error| {
        io.kind() == std::io::ErrorKind::BrokenPipe
            || io.get_ref().is_some_and(|inner| inner.to_string().contains("Broken pipe"))
    };
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>().is_some_and(broken)
            || matches!(c.downcast_ref::<odocal::Error>(), Some(odocal::Error::Io { source, .. }) if broken(source))
    })
}

/// `--threads N`: 1 to the ceiling ([`odocal::settings::MAX_THREADS`]); a
/// usage error otherwise (leaving the option out gives one thread per core).
fn parse_threads(s: &str) -> std::result::Result<usize, String> {
    let max = odocal::settings::MAX_THREADS;
    let at_least_one = "must be at least 1 (leave --threads out for one thread per core)";
    let n: u64 = match s.parse() {
        Ok(n) => n,
        Err(_) if s.trim().strip_prefix('-').is_some_and(|r| r.parse::<f64>().is_ok()) => {
            return Err(format!("{at_least_one}, got {s}"))
        }
        Err(e) => return Err(format!("{e}")),
    };
    match usize::try_from(n) {
        Ok(0) => Err(at_least_one.into()),
        Ok(n) if n <= max => Ok(n),
        _ => Err(format!("{n} is above the ceiling of {max} worker threads")),
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
    // On one line, and with any control character a path or a value carried
    // into the message escaped visibly: a file name holding `ESC[2J` must
    // not clear the user's terminal.
    odocal::output::visible(&line.replace('\n', " ")).into_owned()
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
        Command::Validate(a) => validate::run(a, &bars),
        Command::Compensate(a) => done(compensate::run(a, &bars)),
        // The demo shows a calibration; it is not one to deploy.
        Command::Demo(a) => calibrate::demo_cmd(a, &bars).map(|_| Outcome::Done),
        Command::Experiment(a) => done(experiment::run(a, &bars)),
        Command::Import(a) => done(import::run(a)),
        Command::Inspect(a) => done(inspect::run(a)),
        Command::Follow(a) => done(follow::run(a, &bars)),
        Command::History(a) => done(history::run(a)),
    }
}
