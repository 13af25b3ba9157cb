//! `odocal calibrate` and `odocal demo`: a calibration, its reports (text,
//! JSON, HTML, parameter file) and its exit code.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::output::is_stdout;
use anyhow::{Context, Result};
use clap::Args;
use odocal::settings::{Caller, ManifestSettings, SettingsAccount};
use odocal::{
    segment, sim, CalibrationOptions, CalibrationReport, Drive, Extrinsics, Holdout, Method, ParamSet, Theta,
    VerdictLevel,
};

use crate::args::{CalibrationArgs, HalfArg, HelpArgs, ThetaArg};
use crate::io::{drive_entry, json_text, load_drive_with_scale, load_truth, print_warnings, truth_of};
use crate::output::{refuse_foreign_sidecar, refuse_sidecar_onto_drive, refuse_stdout, write_texts, Files};
use crate::progress::Bars;
use crate::simulate::sim_options;
use crate::Outcome;

/// Arguments of `odocal calibrate`.
#[derive(Args)]
pub struct CalibrateArgs {
    /// Drive CSV or manifest (.toml); several are fitted jointly.
    ///
    /// The drive: a canonical CSV (docs/reference.md, "The drive CSV") or a
    /// drive manifest (.toml).
    /// Several drives of one vehicle are fitted jointly (segments never span
    /// two drives; their sample times must agree).
    #[arg(required = true, num_args = 1..)]
    drive: Vec<PathBuf>,
    #[command(flatten)]
    calibration: CalibrationArgs,
    /// Write the JSON report here ("-": stdout).
    ///
    /// "-" writes it to stdout instead of the text report.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Record the result in this vehicle's history (with --db).
    ///
    /// One row per drive and method: a drive already recorded for the
    /// vehicle by the same method is recognised and not counted twice.
    #[arg(long, requires = "db", value_name = "ID", value_parser = crate::args::vehicle_id)]
    vehicle: Option<String>,
    /// The history database (SQLite; created if missing) for --vehicle.
    #[arg(long, requires = "vehicle", value_name = "FILE")]
    db: Option<PathBuf>,
    #[command(flatten)]
    help: HelpArgs,
}

/// Arguments of `odocal demo`.
#[derive(Args)]
pub struct DemoArgs {
    /// Seed of the simulated drive [default: 1].
    ///
    /// `--seed` seeds the calibration's random batches.
    #[arg(long, default_value_t = 1, hide_default_value = true, value_parser = crate::args::whole::<u64>)]
    sim_seed: u64,
    /// Route length, km.
    #[arg(long, default_value_t = 24.0, allow_hyphen_values = true, value_parser = crate::simulate::route_length_km)]
    length_km: f64,
    /// paper (default), off, white, high or random:N noise.
    #[arg(long, default_value = "paper", hide_default_value = true, value_parser = crate::simulate::noise_preset)]
    noise: String,
    /// Also write the simulated drive here.
    #[arg(long)]
    out: Option<PathBuf>,
    #[command(flatten)]
    calibration: CalibrationArgs,
    /// Write the JSON report here ("-": stdout).
    ///
    /// "-" writes it to stdout instead of the text report.
    #[arg(long)]
    json: Option<PathBuf>,
    #[command(flatten)]
    help: HelpArgs,
}

/// Calibrates the drive(s) named on the command line.
pub fn calibrate_cmd(a: CalibrateArgs, bars: &Bars) -> Result<Outcome> {
    let mut files = Files::default();
    for p in &a.drive {
        files.drive("the drive being calibrated", p);
    }
    if let Some(db) = &a.db {
        // `-`, a file that is no history or cannot be written: named before the work.
        crate::history::check_db(db)?;
    }
    files.output("--db", a.db.as_deref());
    calibration_files(&mut files, &a.calibration, a.json.as_deref())?;
    let mut drives = Vec::with_capacity(a.drive.len());
    // The first drive that states a wheel scale, by name: θ is shared, so
    // every drive must count wheel revolutions alike.
    let mut wheel_scale: Option<(String, String)> = None;
    let mut manifests = Vec::new();
    for p in &a.drive {
        let (d, w, m) = load_drive_with_scale(p)?;
        if let Some(why) = odocal::wheel_scale_mismatch(&mut wheel_scale, &p.display().to_string(), w.as_deref()) {
            anyhow::bail!("one θ cannot be calibrated on drives that count wheel revolutions differently: {why}");
        }
        manifests.extend(m);
        drives.push(d);
    }
    let others = load_validation_drives(&a.calibration.validate_on, wheel_scale.clone())?;
    let wheel_scale = wheel_scale.map(|(_, w)| w);
    let fingerprints = distinct_drives(&a.drive, &drives, &others)?;
    let first = &a.drive[0];
    let (drive, truth) = if drives.len() == 1 {
        let truth = load_truth(first, &drives[0]).as_ref().map(truth_of);
        (drives.swap_remove(0), truth)
    } else {
        let refs: Vec<&Drive> = drives.iter().collect();
        (Drive::concat(&refs).context("calibrating several drives jointly")?, None)
    };
    let job = Job {
        separate: &drives,
        drive: &drive,
        input: a.drive.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", "),
        source: Some((first.as_path(), wheel_scale.as_deref())),
        manifests: &manifests,
        truth,
        others,
        fingerprints,
        history: a.vehicle.as_deref().zip(a.db.as_deref()).map(|h| (h, a.drive.as_slice())),
    };
    run_calibration(job, &a.calibration, a.json.as_deref(), bars)
}

/// Simulates a drive, calibrates it and compares the result with the truth.
pub fn demo_cmd(a: DemoArgs, bars: &Bars) -> Result<Outcome> {
    let mut files = Files::default();
    if let Some(p) = &a.out {
        refuse_stdout("--out", p, "the demo writes the drive's sidecar beside it")?;
        refuse_sidecar_onto_drive("--out", p)?;
        refuse_foreign_sidecar("--out", p)?;
    }
    files.output("--out", a.out.as_deref());
    files.output(
        "the sidecar beside --out (its name with .json)",
        a.out.as_deref().map(sim::SimSidecar::path_beside).as_deref(),
    );
    calibration_files(&mut files, &a.calibration, a.json.as_deref())?;
    let o = sim_options(a.sim_seed, a.length_km, &a.noise)?;
    bars.stage("simulating");
    let sim = sim::simulate(&o).map_err(crate::simulate::flag_error)?;
    bars.finish();
    if let Some(p) = &a.out {
        sim.drive.write_csv(p)?;
        sim.sidecar.write_beside(p)?;
    }
    let others = load_validation_drives(&a.calibration.validate_on, None)?;
    let fingerprints = distinct_drives(&[PathBuf::from("simulated drive")], std::slice::from_ref(&sim.drive), &others)?;
    if !files.any_stdout() {
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
    let job = Job {
        drive: &sim.drive,
        input: "simulated drive".into(),
        source: None,
        manifests: &[],
        truth: Some(truth_of(&sim.sidecar)),
        others,
        fingerprints,
        separate: &[],
        history: None,
    };
    run_calibration(job, &a.calibration, a.json.as_deref(), bars)
}

/// The files a calibration reads besides its drives (`--validate-on`,
/// `--theta0`, `--noise-model`) and writes (`--json`, `--report`,
/// `--params-out`), added to `files` and checked.
fn calibration_files(files: &mut Files, args: &CalibrationArgs, json: Option<&Path>) -> Result<()> {
    for p in &args.validate_on {
        files.drive("the --validate-on drive", p);
    }
    if let Some(p) = args.theta0.as_ref().and_then(ThetaArg::path) {
        files.input("the --theta0 parameter file", p);
    }
    if let Some(p) = &args.noise_model {
        files.input("the --noise-model file", p);
    }
    files
        .output("--json", json)
        .output("--report", args.report.as_deref())
        .output("--params-out", args.params_out.as_deref());
    files.check()
}

/// Refuses a drive given twice (the same samples): among the calibration
/// drives `named`, and between them and the `--validate-on` drives.
/// Returns each drive's report entry (role, path, fingerprint).
fn distinct_drives(paths: &[PathBuf], drives: &[Drive], others: &[OtherDrive]) -> Result<Vec<serde_json::Value>> {
    let names: Vec<String> = paths.iter().map(|p| p.display().to_string()).collect();
    let several = names.len() > 1;
    let mut all: Vec<(String, &Drive)> = names
        .iter()
        .zip(drives)
        .enumerate()
        .map(|(i, (n, d))| (if several { format!("drive {} ({n})", i + 1) } else { n.clone() }, d))
        .collect();
    all.extend(others.iter().map(|(name, d, _)| (format!("the --validate-on drive {name}"), d)));
    let refs: Vec<(&str, &Drive)> = all.iter().map(|(n, d)| (n.as_str(), *d)).collect();
    let prints = odocal::refuse_duplicates(&refs)?;
    let roles = names
        .iter()
        .map(|n| ("calibration", n.as_str()))
        .chain(others.iter().map(|(n, _, _)| ("validation", n.as_str())));
    Ok(roles.zip(&prints).map(|((role, name), fp)| drive_entry(role, name, fp)).collect())
}

/// A `--validate-on` drive: its name, the drive and its manifest's settings.
type OtherDrive = (String, Drive, Option<ManifestSettings>);

/// What a calibration runs on.
struct Job<'a> {
    /// The drive (several joined).
    drive: &'a Drive,
    /// The input as the reports name it: every drive file, comma-separated.
    input: String,
    /// The input file and how to read c_e (ticks per revolution or nominal
    /// circumference) when the drive came from a manifest; `None` for a
    /// simulated drive.
    source: Option<(&'a Path, Option<&'a str>)>,
    /// The calibration settings of the drives' manifests.
    manifests: &'a [ManifestSettings],
    /// The true θ and reference mount, for a simulated drive (or one whose
    /// sidecar is bound to it).
    truth: Option<(Theta, Extrinsics)>,
    /// The `--validate-on` drives.
    others: Vec<OtherDrive>,
    /// Each drive's report entry (role, path, fingerprint).
    fingerprints: Vec<serde_json::Value>,
    /// The drives `drive` was joined from, when several (their separate
    /// fits give the between-drive σ: `Calibration::drives`).
    separate: &'a [Drive],
    /// The vehicle and history database to record the result in, and the
    /// drive files (`--vehicle`, `--db`).
    history: Option<((&'a str, &'a Path), &'a [PathBuf])>,
}

/// Calibrates the job's drive and writes every report asked for.
fn run_calibration(job: Job<'_>, args: &CalibrationArgs, json: Option<&Path>, bars: &Bars) -> Result<Outcome> {
    let Job { drive, input, source, manifests, truth: truth_theta, others, fingerprints, separate, history } = job;
    let settings = args.settings()?;
    let resolved = settings.resolve(manifests, Caller::CommandLine)?;
    let (opts, account) = (&resolved.options, &resolved.account);
    // The extrinsics the command line gives apply to every validation drive.
    let given = resolved.given_extrinsics;
    let holdout = holdout(args.holdout, &others)?;
    // The data the report's validation ran on (truth and HTML report).
    let split = holdout.as_ref().map(|h| h.split(drive)).transpose()?;
    let held = split.as_ref().map(|(_, held)| held.as_ref());
    // Several drives fitted whole (not a half of them held out): the
    // between-drive σ from their separate fits.
    let separate: Vec<&Drive> = separate.iter().collect();
    let r = calibrate(drive, (holdout.as_ref(), &others), (given, args.carry_heading_offset), &separate, opts, bars)
        .map_err(|e| with_hint(e, source, args, &opts.method, bars))?;
    let wheel_scale = source.and_then(|(_, w)| w);
    bars.finish();
    let whole = drive;
    let drive = held.unwrap_or(drive);
    let truth = truth_theta.map(|(t, mount)| truth_error(drive, &t, &mount, opts).map(|e| (t, e))).transpose()?;
    let truth_ref = truth.as_ref().map(|(t, e)| (t, *e));
    let prints = calibration_fingerprints(&fingerprints);
    // Every output is rendered, then all are written as one, then the
    // history records the calibration: a failure or an interruption
    // leaves no output out of step with the others or with the history.
    let mut outputs: Vec<(&Path, String)> = Vec::new();
    if let Some(p) = &args.params_out {
        // The σ that stands for the result (the verdict's, the JSON's `sigma`).
        let mut f = r.param_file(&input);
        f.node = args.params_node.clone();
        f.mapping = args.params_mapping;
        f.provenance.push(("fingerprint".into(), prints.clone()));
        // What c_e, c_d and d are per: `validate` compares it with a drive's.
        if let Some(w) = wheel_scale {
            f.provenance.push(("wheel_scale".into(), w.to_string()));
        }
        outputs.push((p, f.text_for(p)?));
    }
    if let Some(p) = &args.report {
        // The drives the segments come from: the --validate-on drives, or
        // the calibration's own (each with its heading offset after a joint fit).
        let starts = if others.is_empty() {
            drive.drive_starts().to_vec()
        } else {
            drive_starts(others.iter().map(|(_, d, _)| d.len()))
        };
        let truth = truth_theta.as_ref().map(|(t, mount)| (t, *mount));
        // The calibration's own drives by their files, when the segments are theirs.
        let own: Vec<String> = if others.is_empty() { drive_paths(&fingerprints, "calibration") } else { Vec::new() };
        outputs.push((p, html_report((drive, &starts, own), &r, opts, (&input, &prints), truth)?));
    }
    let outcome = if r.verdict.level == VerdictLevel::Rejected { Outcome::Rejected } else { Outcome::Done };
    if let Some(p) = json {
        outputs.push((p, json_text(r.to_json(fingerprints, truth_ref, wheel_scale, Some(account))?)?));
    }
    write_texts(&outputs)?;
    if let Some((vehicle_db, sources)) = history {
        crate::history::record_calibration(vehicle_db, whole, sources, &prints, &r)?;
    }
    let on_stdout = [json, args.report.as_deref(), args.params_out.as_deref()].into_iter().flatten().any(is_stdout);
    if on_stdout {
        print_warnings(&r.warnings);
        return Ok(outcome);
    }
    print_text_report(&r, truth_ref, wheel_scale, account)?;
    Ok(outcome)
}

/// The fingerprints of the calibration drives (not the validation drives),
/// comma separated: a parameter file's and the HTML report's provenance.
fn calibration_fingerprints(entries: &[serde_json::Value]) -> String {
    let of_role = |e: &&serde_json::Value| e["role"] == "calibration";
    let prints: Vec<&str> = entries.iter().filter(of_role).filter_map(|e| e["fingerprint"].as_str()).collect();
    prints.join(", ")
}

/// Reads the `--validate-on` drives, which must count wheel revolutions as
/// the calibration's drives do and as each other (`seen`: the first of the
/// calibration's drives that states a wheel scale, and the scale).
fn load_validation_drives(paths: &[PathBuf], mut seen: Option<(String, String)>) -> Result<Vec<OtherDrive>> {
    let mut others = Vec::with_capacity(paths.len());
    for p in paths {
        let (d, w, m) = load_drive_with_scale(p).with_context(|| format!("--validate-on {}", p.display()))?;
        let name = p.display().to_string();
        if let Some(why) = odocal::wheel_scale_mismatch(&mut seen, &name, w.as_deref()) {
            anyhow::bail!("--validate-on {name}: θ would be judged in another unit: {why}");
        }
        others.push((name, d, m));
    }
    Ok(others)
}

/// The data the calibration is validated on: a half of the drive
/// (`--holdout`), the `--validate-on` drives joined, or none (the drive itself).
fn holdout(half: Option<HalfArg>, others: &[OtherDrive]) -> Result<Option<Holdout>> {
    Ok(match half {
        Some(HalfArg::FirstHalf) => Some(Holdout::FirstHalf),
        Some(HalfArg::SecondHalf) => Some(Holdout::SecondHalf),
        None if others.is_empty() => None,
        None => {
            let refs: Vec<&Drive> = others.iter().map(|(_, d, _)| d).collect();
            Some(Holdout::Other(Drive::concat(&refs).context("--validate-on")?))
        }
    })
}

/// Runs the calibration of `drive`, validated on the `holdout` or, with
/// `--validate-on`, on each other drive (`given`: the extrinsics the
/// command line states, which apply to each, and whether an estimated
/// heading offset is carried to them); `drives`: those `drive` was joined
/// from, fitted alone too for the between-drive σ.
fn calibrate(
    drive: &Drive,
    (holdout, others): (Option<&Holdout>, &[OtherDrive]),
    (given, carry_heading_offset): (ParamSet, bool),
    drives: &[&Drive],
    opts: &CalibrationOptions,
    bars: &Bars,
) -> odocal::Result<CalibrationReport> {
    let cb = |e| bars.event(e);
    // Each validation drive with the extrinsics that apply to it (its own
    // manifest's `[reference]` where the calibration neither estimates nor
    // is given them: odocal::assess::validation_drives).
    let validation: Vec<odocal::ValidationDrive> = others
        .iter()
        .map(|(name, d, m)| odocal::ValidationDrive {
            name,
            drive: d,
            reference: m.as_ref().and_then(|m| m.reference.as_ref()),
        })
        .collect();
    let run = odocal::Calibration { progress: Some(&cb), drives, ..odocal::Calibration::new(drive, opts) };
    match (validation.is_empty(), holdout) {
        (true, Some(h)) => odocal::Calibration { holdout: Some(h), ..run }.run(),
        (true, None) => run.run(),
        (false, _) => odocal::Calibration { validate_on: &validation, given, carry_heading_offset, ..run }.run(),
    }
}

/// The calibration's error; when a parameter is not observable, with the
/// command line that calibrates c_e alone.
fn with_hint(
    e: odocal::Error,
    source: Option<(&Path, Option<&str>)>,
    args: &CalibrationArgs,
    method: &Method,
    bars: &Bars,
) -> anyhow::Error {
    let odocal::Error::NotObservable { params, .. } = &e else {
        return match (e, source) {
            // The drives the library joined as "held-out drive", by name.
            (odocal::Error::InvalidDrive { context, reason }, _)
                if context == "held-out drive" && !args.validate_on.is_empty() =>
            {
                let names: Vec<String> = args.validate_on.iter().map(|p| p.display().to_string()).collect();
                let context = format!("--validate-on {}", names.join(","));
                odocal::Error::InvalidDrive { context, reason }.into()
            }
            (e, Some((p, _))) => crate::io::name_drive(e, p).into(),
            (e, None) => e.into(),
        };
    };
    bars.finish();
    // Holding c_d, t_r, d calibrates c_e alone; with c_e or an extrinsic
    // not observable, that command (or --auto-fix) would fail alike.
    let yaw_only = params.iter().all(|p| ["c_d", "t_r", "d"].contains(p));
    let hint = match source {
        _ if params.contains(&"c_e") => "; c_e follows from the distance driven: check that the vehicle moves in \
                                           this drive (the wheel speeds and the reference positions)"
            .to_string(),
        _ if !yaw_only => format!("; hold them with --fix {}", params.join(",")),
        _ if args.auto_fix => String::new(),
        Some((p, _)) => format!("; run: {} (or add --auto-fix)", c_e_only_command(p, args, method)),
        None => "; or add --auto-fix".into(),
    };
    anyhow::anyhow!("{e}{hint}")
}

/// The first sample of each of drives of `lengths` samples joined one
/// after the other ([`Drive::concat`]).
fn drive_starts(lengths: impl Iterator<Item = usize>) -> Vec<usize> {
    lengths
        .scan(0, |n, len| {
            let start = *n;
            *n += len;
            Some(start)
        })
        .collect()
}

/// Ē_p of the true θ on the validation segments of `drive` with the true
/// reference mount: the truth's row of the text, JSON and HTML reports.
fn truth_error(drive: &Drive, theta: &Theta, mount: &Extrinsics, opts: &CalibrationOptions) -> Result<f64> {
    // Ē_p alone: the truth needs no verdict (the drive's own fit would cost
    // two more calibrations).
    let v = odocal::ValidateOptions {
        segments: opts.validation.clone(),
        extrinsics: *mount,
        fit_drive: false,
        ..Default::default()
    };
    Ok(odocal::validate(drive, theta, &v, None)?.validation.mean_position_error_m)
}

/// The paths of the drives of `role` in the report entries `entries`
/// ([`drive_entry`]), in order.
fn drive_paths(entries: &[serde_json::Value], role: &str) -> Vec<String> {
    entries.iter().filter(|e| e["role"] == role).filter_map(|e| e["path"].as_str().map(str::to_string)).collect()
}

/// The HTML report of the calibration (`--report`;
/// `starts`: the first sample of each `--validate-on` drive in `drive`, or
/// of each calibration drive; `names`: the calibration drives' names when
/// the segments are theirs (the `--validate-on` drives' come with the
/// report); `truth`: the true θ and reference mount).
fn html_report(
    (drive, starts, names): (&Drive, &[usize], Vec<String>),
    r: &CalibrationReport,
    opts: &CalibrationOptions,
    (input, fingerprint): (&str, &str),
    truth: Option<(&Theta, Extrinsics)>,
) -> Result<String> {
    let val = segment::validation_segments(drive, &opts.validation)?;
    // The date the calibration's parameter file records.
    let date = r.param_file(input).provenance.into_iter().find(|(k, _)| k == "date").map(|(_, v)| v);
    let base = odocal_report::ReportInput::of_calibration(input, r, (drive, &val, starts), truth.map(|t| t.0));
    let html = odocal_report::ReportInput {
        drive_names: if names.len() == drive.drive_starts().len() { names } else { base.drive_names.clone() },
        provenance: vec![
            ("method".into(), r.method.clone()),
            ("input".into(), input.to_string()),
            ("fingerprint".into(), fingerprint.to_string()),
            ("σ of θ".into(), r.result_sigma().covers.to_string()),
            ("odocal".into(), env!("CARGO_PKG_VERSION").into()),
            ("date".into(), date.unwrap_or_default()),
        ],
        truth_extrinsics: truth.map(|t| t.1).unwrap_or_default(),
        ..base
    }
    // What the import warned about, as on stderr and in the JSON, before the calibration's warnings.
    .with_import_warnings(crate::io::import_warnings());
    Ok(odocal_report::render_html(&html)?)
}

/// The report for humans: the heading first, then the warnings (stderr),
/// then the rest.
fn print_text_report(
    r: &CalibrationReport,
    truth: Option<(&Theta, f64)>,
    wheel_scale: Option<&str>,
    account: &SettingsAccount,
) -> Result<()> {
    let text = r.render_text(truth, wheel_scale, Some(account));
    let (head, rest) = text.split_once('\n').unwrap_or((&text, ""));
    println!("{head}");
    std::io::stdout().flush()?;
    print_warnings(&r.warnings);
    print!("{rest}");
    std::io::stdout().flush()?;
    Ok(())
}

/// The command line that calibrates c_e alone on `path` with `method`, with
/// the user's other settings, for the error when c_d, t_r, d are not observable.
fn c_e_only_command(path: &Path, args: &CalibrationArgs, method: &Method) -> String {
    let mut cmd = format!("odocal calibrate {} --method {method}", path.display());
    if let Some(h) = args.holdout {
        cmd.push_str(match h {
            HalfArg::FirstHalf => " --holdout first-half",
            HalfArg::SecondHalf => " --holdout second-half",
        });
    }
    cmd.push_str(" --fix c_d,t_r,d");
    // Method eiv fits every segment; the others select turning ones.
    if !matches!(method, Method::Eiv(_)) {
        cmd.push_str(" --min-yaw-rate 0");
    }
    cmd
}
