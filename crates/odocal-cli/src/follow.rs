//! `odocal follow`: drives replayed in the order given as if live through
//! the online calibrator, with gated write-back to the vehicle's history
//! and parameter file.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use odocal::{ParamFile, Theta};
use odocal_history::{follow, FollowEvent, FollowOptions, History};
use odocal_online::gate::{Action, GateDecision, Gates};
use odocal_online::{Calibrator, OnlineOptions, RandomWalk};
use serde_json::{json, Value};

use crate::args::{HelpArgs, ThetaArg};
use crate::output::{report_line, write_text, Files};
use crate::progress::Bars;

/// The method the parameter files written name.
const METHOD: &str = "online";

/// Arguments of `odocal follow`.
#[derive(Args)]
pub struct FollowArgs {
    /// Drive CSVs or manifests, replayed in the order given.
    #[arg(required = true, num_args = 1..)]
    drive: Vec<PathBuf>,
    /// The vehicle's identifier in the history.
    #[arg(long, value_name = "ID", value_parser = crate::args::vehicle_id)]
    vehicle: String,
    /// The history database (SQLite; created if missing).
    ///
    /// The replay starts from the vehicle's last recorded parameters in it
    /// that were not rejected (else --theta0); each drive's write-back decision is logged in its
    /// table `decisions`, each written update in `calibrations`. A drive
    /// followed before or calibrated for the vehicle is skipped: replaying
    /// it would count its samples twice.
    #[arg(long, value_name = "FILE")]
    db: PathBuf,
    /// Write each written update to this parameter file (.yaml, .json;
    /// "-": the last written update once at the end, as YAML on stdout).
    #[arg(long, value_name = "FILE", value_parser = crate::args::params_out_path)]
    params_out: Option<PathBuf>,
    /// Write the per-drive report as JSON ("-": stdout).
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// θ_0 when the history holds none: c_e,c_d,t_r,d (SI) or a parameter file.
    #[arg(long, allow_hyphen_values = true)]
    theta0: Option<ThetaArg>,
    /// Informative driving (s) over which each parameter of θ must stay
    /// within its --max-sigma threshold of its current value before an
    /// update is written.
    #[arg(long, default_value_t = 10.0, value_name = "S", help_heading = GATES)]
    steady_s: f64,
    /// A segment's weight, 1e-6 to 1 [default: 0.005].
    ///
    /// The weight of one segment's normal equations. Smaller values make
    /// the estimate average over more segments
    /// (steadier, slower to follow a change).
    #[arg(long, value_name = "F", help_heading = ONLINE)]
    information_scale: Option<f64>,
    /// Fold only segments whose peak yaw rate is at least this, rad/s [default: 0, every segment].
    #[arg(long, value_name = "RAD_PER_S", help_heading = ONLINE, value_parser = crate::args::yaw_rate)]
    min_yaw_rate: Option<f64>,
    #[command(flatten)]
    expert: ExpertArgs,
    #[command(flatten)]
    help: HelpArgs,
}

/// Help heading of the online calibrator's options.
const ONLINE: &str = "Online calibrator";
/// Help heading of the write-back gates' thresholds.
const GATES: &str = "Write-back gates";

/// The online calibrator's and the gates' settings with documented
/// defaults (`odocal_online::OnlineOptions`, `odocal_online::gate::Gates`),
/// shown by `--help-all`, not `-h`/`--help`.
#[derive(Args)]
struct ExpertArgs {
    /// Factors on the recursion's sd of c_e,c_d,t_r,d for the σ reported
    /// [default: 1.1,4.6,6.3,4.1].
    ///
    /// The factors that make ±2σ cover the truth 90 % of the time on
    /// simulated drives (docs/validation.md); θ's updates do not use them.
    #[arg(long, allow_hyphen_values = true, value_name = "F,F,F,F", help_heading = ONLINE, hide_short_help = true)]
    sigma_factors: Option<Four>,
    /// The parameters' random walk: sd after one hour of driving of
    /// c_e (fraction), c_d (m), t_r (m), d (m/(m/s²)) [default: 7e-4,2.5e-4,5e-3,2.5e-4].
    ///
    /// How fast θ may drift; 0 holds a parameter constant; at most
    /// 0.1,0.05,1,0.05.
    #[arg(long, allow_hyphen_values = true, value_name = "CE,CD,TR,D", help_heading = ONLINE, hide_short_help = true)]
    random_walk: Option<Four>,
    /// θ's sd when the history holds no σ for the vehicle: c_e (fraction),
    /// c_d (m), t_r (fraction), d (m/(m/s²)), each from 1e-6 to 0.5,0.05,0.5,0.05
    /// [default: 0.02,5e-3,0.05,2e-3].
    #[arg(long, allow_hyphen_values = true, value_name = "CE,CD,TR,D", help_heading = ONLINE, hide_short_help = true)]
    prior_sd: Option<Four>,
    /// The reference heading offset's sd at the start of each drive, rad [default: 0.05].
    #[arg(long, value_name = "RAD", help_heading = ONLINE, hide_short_help = true)]
    heading_offset_prior_sd: Option<f64>,
    /// A folded segment is informative driving when its peak yaw rate
    /// is at least this, rad/s [default: 0.15].
    #[arg(long, value_name = "RAD_PER_S", help_heading = ONLINE, hide_short_help = true)]
    informative_yaw_rate: Option<f64>,
    /// Gauss-Newton iterations per folded segment, 1 to 100 [default: 2].
    #[arg(long, value_name = "N", help_heading = ONLINE, hide_short_help = true, value_parser = crate::args::whole::<usize>)]
    iterations_per_segment: Option<usize>,
    /// Informative driving over which θ's track is kept for the steadiness gate, s [default: 120].
    #[arg(long, value_name = "S", help_heading = ONLINE, hide_short_help = true)]
    steady_window_s: Option<f64>,
    /// Validation segments of the held-out gate (the drive's most recent), 1 to 10000 [default: 3].
    #[arg(long, value_name = "N", help_heading = ONLINE, hide_short_help = true, value_parser = crate::args::whole::<usize>)]
    recent_validation_segments: Option<usize>,
    /// Largest σ written of c_e (fraction), c_d (m), t_r (m), d (m/(m/s²))
    /// [default: 1e-3,1e-3,0.02,1e-3].
    #[arg(long, allow_hyphen_values = true, value_name = "CE,CD,TR,D", help_heading = GATES, hide_short_help = true)]
    max_sigma: Option<Four>,
    /// Largest change from the stored calibration written without a person
    /// (larger ones are flagged): c_e (fraction), c_d (m), t_r (m), d
    /// (m/(m/s²)) [default: 0.01,5e-3,0.05,5e-3].
    #[arg(long, allow_hyphen_values = true, value_name = "CE,CD,TR,D", help_heading = GATES, hide_short_help = true)]
    max_change: Option<Four>,
}

/// Four numbers, `a,b,c,d`: one per parameter of θ.
#[derive(Debug, Clone, Copy)]
struct Four([f64; 4]);

impl std::str::FromStr for Four {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Four, String> {
        let v: Vec<f64> = s
            .split(',')
            .map(|x| x.trim().parse::<f64>().map_err(|_| format!("'{}' is not a number", x.trim())))
            .collect::<std::result::Result<_, _>>()?;
        let v: [f64; 4] = v.try_into().map_err(|v: Vec<f64>| format!("4 numbers expected, got {}", v.len()))?;
        Ok(Four(v))
    }
}

/// Replays the drives through the library's `odocal_history::follow` and
/// prints what it reports; writes each written update to `--params-out`.
/// An error at a drive stops the replay: the drives before it stay
/// recorded in the history, and `--json` (and `--params-out -`) still
/// get what was done, the JSON with the error and the drive it stopped at.
pub fn run(a: FollowArgs, bars: &Bars) -> Result<()> {
    // The options' values first: a value out of its range is a usage
    // error, whatever else the command line holds.
    if !(a.steady_s.is_finite() && a.steady_s >= 0.0) {
        let why = format!("--steady-s must be a non-negative number of seconds, got {}", a.steady_s);
        return Err(odocal::Error::InvalidFlags(why).into());
    }
    let opts =
        FollowOptions { theta0: a.theta0.as_ref().map(|t| t.theta), online: online_options(&a)?, gates: gates(&a)? };
    crate::output::refuse_stdout("--db", &a.db, "the history is a database file")?;
    let mut files = Files::default();
    for p in &a.drive {
        files.drive("a drive being followed", p);
    }
    if let Some((p, _)) = a.theta0.as_ref().and_then(|t| t.file.as_ref()) {
        files.input("the --theta0 parameter file", p);
    }
    files
        .output("--db", Some(&a.db))
        .output("--json", a.json.as_deref())
        .output("--params-out", a.params_out.as_deref());
    files.check()?;
    // A drive that is not there is named before the history is opened (and created).
    if let Some(p) = a.drive.iter().find(|p| !p.exists()) {
        bail!("{}: no such drive file", p.display());
    }
    let mut db = History::open_to_write(&a.db)?;
    // With an output on stdout (`--json -`, `--params-out -`) the text
    // report goes to stderr, so stdout holds that output alone.
    let params_to_stdout = a.params_out.as_deref().is_some_and(crate::output::is_stdout);
    let text_to_stderr = params_to_stdout || a.json.as_deref().is_some_and(crate::output::is_stdout);
    let mut r = Replayed {
        a: &a,
        bars,
        text_to_stderr,
        params_to_stdout,
        entries: Vec::with_capacity(a.drive.len()),
        handled: 0,
        failed_at: None,
        last_written: None,
        start: String::new(),
        followed: Vec::new(),
        wheel_scale: None,
    };
    let error = follow(&mut db, &a.vehicle, &a.drive, &opts, |event| r.on(event)).err();
    // The drive the replay stopped at: the one being handled when its
    // report failed, else the one after those handled.
    let stopped = r.failed_at.unwrap_or(r.handled);
    let wrote = r.write_outputs(error.as_ref().map(|e| (stopped, crate::one_line(e))));
    match error {
        Some(e) => {
            if let Err(w) = wrote {
                eprintln!("warning: {}", crate::one_line(&w));
            }
            Err(e)
        }
        None => wrote,
    }
}

/// What [`run`] keeps of the replay as it goes: the text report's
/// settings, the JSON report's entries and the written updates.
struct Replayed<'a> {
    a: &'a FollowArgs,
    bars: &'a Bars,
    /// The text report goes to stderr (an output is on stdout).
    text_to_stderr: bool,
    /// `--params-out -`.
    params_to_stdout: bool,
    /// One per drive handled, in order (the JSON's `drives`).
    entries: Vec<Value>,
    /// The drives handled (skipped or followed): each is reported once.
    handled: usize,
    /// The index of the drive whose report failed (a parameter file not
    /// written), when one did.
    failed_at: Option<usize>,
    /// The last written update's file, for `--params-out -`.
    last_written: Option<ParamFile>,
    /// Where the recursion started.
    start: String,
    /// The drives the recursion followed, in order (source, fingerprint):
    /// a written estimate rests on all of them, and its file names them.
    followed: Vec<(String, String)>,
    /// The first wheel scale a followed drive stated (they share it; a
    /// drive CSV states none): what a written estimate's c_e is per.
    wheel_scale: Option<String>,
}

impl Replayed<'_> {
    fn say(&self, line: String) {
        report_line(self.text_to_stderr, &line);
    }

    /// Reports one event of the replay.
    fn on(&mut self, event: FollowEvent) -> Result<()> {
        let a = self.a;
        let vehicle = &a.vehicle;
        match event {
            FollowEvent::Start { theta, origin } => {
                self.say(format!("vehicle '{vehicle}': starting from {theta} ({origin})"));
                self.start = origin;
            }
            FollowEvent::Log(line) => eprintln!("{line}"),
            FollowEvent::Progress(p) => self.bars.event(p),
            FollowEvent::Skipped { source, fingerprint, row } => {
                self.handled += 1;
                self.bars.finish();
                let short = &fingerprint[..fingerprint.len().min(12)];
                self.say(match &row {
                    Some((id, method)) => format!(
                        "{source}: already recorded for vehicle '{vehicle}' (row {id}, {method}; fingerprint \
                         {short}…); skipped: replaying it would count its samples twice"
                    ),
                    None => {
                        format!("{source}: already followed for vehicle '{vehicle}' (fingerprint {short}…); skipped")
                    }
                });
                self.entries.push(json!({"source": source, "fingerprint": fingerprint, "already_recorded": true,
                    "recorded_row": row.map(|(id, _)| id), "prequential_mean_position_error_m": null, "updates": []}));
            }
            FollowEvent::Followed {
                source,
                fingerprint,
                summary,
                heading_offset_rad,
                drive_time_s,
                decision,
                wheel_scale,
            } => {
                self.handled += 1;
                self.bars.finish();
                // θ_0 from a parameter file of another wheel scale: said once, at the first drive.
                if self.followed.is_empty() && self.start == "θ_0" {
                    let theta0 = a.theta0.as_ref().and_then(|t| t.file.as_ref());
                    let use_ = "the recursion started from θ_0 as it stands";
                    let drive = std::path::Path::new(&source);
                    if let Some(w) = crate::validate::wheel_scale_warning(theta0, wheel_scale.as_deref(), drive, use_) {
                        eprintln!("warning: {w}");
                    }
                }
                self.followed.push((source.clone(), fingerprint.clone()));
                self.wheel_scale = self.wheel_scale.take().or(wheel_scale);
                let e = summary.prequential_mean_position_error_m.map_or("-".into(), |e| format!("{e:.3} m"));
                self.say(format!(
                    "{source}: prequential Ē_p {e} over {} validation segment{}, {} segment{} folded; {}; {}: {}",
                    summary.validation_segments,
                    if summary.validation_segments == 1 { "" } else { "s" },
                    summary.folded_segments,
                    if summary.folded_segments == 1 { "" } else { "s" },
                    decision.theta.display_with_sigma(&decision.sigma),
                    decision.action,
                    decision.reasons.join("; ")
                ));
                self.entries.push(json!({
                    "source": source,
                    "fingerprint": fingerprint,
                    "prequential_mean_position_error_m": summary.prequential_mean_position_error_m,
                    "stored_mean_position_error_m": summary.stored_mean_position_error_m,
                    "validation_segments": summary.validation_segments,
                    "folded_segments": summary.folded_segments,
                    "samples": summary.samples,
                    "heading_offset_rad": heading_offset_rad,
                    "updates": [update_json(&decision, drive_time_s)],
                }));
                if decision.action == Action::Write {
                    let f = param_file(&decision, &self.followed, &self.start, self.wheel_scale.as_deref());
                    match &a.params_out {
                        Some(p) if !self.params_to_stdout => {
                            // The drive is recorded: the JSON reports it, and the replay stops at it.
                            let written = f.text_for(p).map_err(anyhow::Error::from).and_then(|text| {
                                write_text(p, &text).with_context(|| format!("--params-out {}", p.display()))
                            });
                            if written.is_err() {
                                self.failed_at = Some(self.handled - 1);
                            }
                            written?;
                        }
                        _ => self.last_written = Some(f),
                    }
                }
            }
        }
        Ok(())
    }

    /// Writes `--json` and `--params-out -` at the end of the replay: on
    /// `error` (the index of the drive it stopped at, and the message) the
    /// JSON also when some drive was handled, with the error.
    fn write_outputs(&mut self, error: Option<(usize, String)>) -> Result<()> {
        let a = self.a;
        // Before any drive was handled nothing was done: no output.
        if error.is_some() && self.entries.is_empty() {
            return Ok(());
        }
        if let Some(p) = &a.json {
            let mut doc = json!({ "drives": self.entries });
            if let Some((i, message)) = &error {
                let drive = a.drive.get(*i).map(|d| d.display().to_string());
                let number = drive.as_ref().map(|_| i + 1);
                doc["error"] = json!({ "drive": drive, "drive_number": number, "message": message });
            }
            write_text(p, &serde_json::to_string_pretty(&doc)?)?;
        }
        if let (true, Some(p)) = (self.params_to_stdout, &a.params_out) {
            // One document, what a file would hold at the end: a stream of
            // several would not read back as one parameter file.
            match self.last_written.take() {
                Some(f) => write_text(p, &f.text_for(p)?)?,
                None => eprintln!("--params-out -: no update was written, so nothing on stdout"),
            }
        }
        Ok(())
    }
}

/// The online calibrator's options from the command line, checked (by a
/// calibrator made with them) before any drive is read.
fn online_options(a: &FollowArgs) -> Result<OnlineOptions> {
    let mut o = OnlineOptions::default();
    let e = &a.expert;
    if let Some(f) = a.information_scale {
        o.information_scale = f;
    }
    if let Some(r) = a.min_yaw_rate {
        o.segments.min_peak_yaw_rate_rad_per_s = r;
    }
    if let Some(Four(f)) = e.sigma_factors {
        o.sigma_factors = f;
    }
    if let Some(Four([c_e_relative, c_d_m, t_r_m, d])) = e.random_walk {
        o.random_walk = RandomWalk { c_e_relative, c_d_m, t_r_m, d };
    }
    if let Some(Four(p)) = e.prior_sd {
        (o.prior_relative_c_e, o.prior_c_d_m, o.prior_relative_t_r, o.prior_d) = (p[0], p[1], p[2], p[3]);
    }
    let set = |slot: &mut f64, v: Option<f64>| *slot = v.unwrap_or(*slot);
    set(&mut o.heading_offset_prior_sd_rad, e.heading_offset_prior_sd);
    set(&mut o.informative_yaw_rate_rad_per_s, e.informative_yaw_rate);
    set(&mut o.steady_window_s, e.steady_window_s);
    o.iterations_per_segment = e.iterations_per_segment.unwrap_or(o.iterations_per_segment);
    o.recent_validation_segments = e.recent_validation_segments.unwrap_or(o.recent_validation_segments);
    // The library names the option's field (`information_scale`): the
    // command line names the flag that set it, a usage error.
    Calibrator::new(Theta::PAPER_INITIAL, None, 0.025, o.clone()).map_err(|err| match err {
        odocal::Error::InvalidOption { field, reason } => match flag_value(&o, field) {
            Some((flag, value)) => odocal::Error::InvalidFlags(format!("{flag} = {value}: {reason}")),
            None => odocal::Error::InvalidOption { field, reason },
        },
        err => err,
    })?;
    Ok(o)
}

/// The `follow` flag that sets the online option `field`, and its value
/// as the options hold it (`None` for a field no flag sets).
fn flag_value(o: &OnlineOptions, field: &str) -> Option<(&'static str, String)> {
    // Exponent notation outside 1e-6 … 1e9 (`1e300` stays short).
    let num = |v: f64| {
        if v.is_finite() && v != 0.0 && !(1e-6..1e9).contains(&v.abs()) {
            format!("{v:e}")
        } else {
            v.to_string()
        }
    };
    let four = |v: [f64; 4]| v.map(num).join(",");
    let rw = &o.random_walk;
    let prior = [o.prior_relative_c_e, o.prior_c_d_m, o.prior_relative_t_r, o.prior_d];
    Some(match field {
        "prior_relative_c_e" | "prior_c_d_m" | "prior_relative_t_r" | "prior_d" => ("--prior-sd", four(prior)),
        "random_walk" => ("--random-walk", four([rw.c_e_relative, rw.c_d_m, rw.t_r_m, rw.d])),
        "sigma_factors" => ("--sigma-factors", four(o.sigma_factors)),
        "information_scale" => ("--information-scale", num(o.information_scale)),
        "heading_offset_prior_sd_rad" => ("--heading-offset-prior-sd", num(o.heading_offset_prior_sd_rad)),
        "informative_yaw_rate_rad_per_s" => ("--informative-yaw-rate", num(o.informative_yaw_rate_rad_per_s)),
        "steady_window_s" => ("--steady-window-s", num(o.steady_window_s)),
        "iterations_per_segment" => ("--iterations-per-segment", o.iterations_per_segment.to_string()),
        "recent_validation_segments" => ("--recent-validation-segments", o.recent_validation_segments.to_string()),
        "min_peak_yaw_rate_rad_per_s" => ("--min-yaw-rate", num(o.segments.min_peak_yaw_rate_rad_per_s)),
        _ => return None,
    })
}

/// The write-back gates from the command line; every threshold a positive number.
fn gates(a: &FollowArgs) -> Result<Gates> {
    let mut g = Gates { steady_s: a.steady_s, ..Gates::default() };
    if let Some(Four(m)) = a.expert.max_sigma {
        (g.max_sigma_c_e_relative, g.max_sigma_c_d_m, g.max_sigma_t_r_m, g.max_sigma_d) = (m[0], m[1], m[2], m[3]);
    }
    if let Some(Four(m)) = a.expert.max_change {
        (g.max_change_c_e_relative, g.max_change_c_d_m, g.max_change_t_r_m, g.max_change_d) = (m[0], m[1], m[2], m[3]);
    }
    for (flag, v) in [("--max-sigma", a.expert.max_sigma), ("--max-change", a.expert.max_change)] {
        if let Some(Four(v)) = v {
            if v.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
                let why = format!("{flag} must be four positive numbers, got {v:?}");
                return Err(odocal::Error::InvalidFlags(why).into());
            }
        }
    }
    Ok(g)
}

/// The parameter file of a written update. Its verdict is `accepted`:
/// every gate passed (the reasons say how), which is what a file
/// `calibrate` writes with that verdict says too, so a fleet script that
/// deploys the files whose `verdict` is `accepted` deploys `follow`'s.
///
/// The estimate rests on every drive the recursion followed (`followed`:
/// source and fingerprint, in order) and on where it started (`start`: a
/// history row or θ_0): the provenance names the drives as `calibrate`
/// names a joint calibration's (`input` and `fingerprint` comma separated,
/// `drives` their number) and the start as `start`; `wheel_scale` is what
/// c_e, c_d and d are per (the followed drives share it).
fn param_file(
    decision: &GateDecision,
    followed: &[(String, String)],
    start: &str,
    wheel_scale: Option<&str>,
) -> ParamFile {
    debug_assert_eq!(decision.action, Action::Write);
    let s = <[_; 4]>::from(decision.sigma).map(Some);
    let sources: Vec<&str> = followed.iter().map(|(s, _)| s.as_str()).collect();
    let prints: Vec<&str> = followed.iter().map(|(_, f)| f.as_str()).collect();
    let mut f = ParamFile::from_theta(&decision.theta, s, &sources.join(", "), METHOD);
    f.verdict = Some(odocal::VerdictLevel::Accepted.to_string());
    f.verdict_reasons = decision.reasons.clone();
    f.provenance.push(("fingerprint".into(), prints.join(", ")));
    f.provenance.push(("drives".into(), followed.len().to_string()));
    f.provenance.push(("start".into(), start.to_string()));
    if let Some(w) = wheel_scale {
        f.provenance.push(("wheel_scale".into(), w.to_string()));
    }
    f
}

/// A decision in the JSON report.
fn update_json(d: &GateDecision, drive_time_s: f64) -> Value {
    json!({
        "decision": d.action.to_string(),
        "reasons": d.reasons,
        "drive_time_s": drive_time_s,
        "theta": d.theta,
        "sigma": d.sigma,
    })
}
