//! `odocal follow`: drives replayed in the order given as if live through
//! the online calibrator, with gated write-back to the vehicle's history
//! and parameter file.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use odocal::history::{CalibrationRecord, Decision, History};
use odocal::online::gate::{Action, GateDecision, Gates};
use odocal::online::{Calibrator, OnlineOptions};
use odocal::{Drive, DriveStream, ParamFile, Progress, Theta};
use serde_json::{json, Value};

use crate::args::ThetaArg;
use crate::io::load_drive_with_scale;
use crate::output::{write_text, Files};
use crate::progress::Bars;

/// The history's `method` of the rows `follow` writes.
const METHOD: &str = "online";

/// Samples per chunk pushed (10 s at 40 Hz).
const CHUNK: usize = 400;

/// Arguments of `odocal follow`.
#[derive(Args)]
pub struct FollowArgs {
    /// Drive CSVs or manifests, replayed in the order given.
    #[arg(required = true, num_args = 1..)]
    drive: Vec<PathBuf>,
    /// The vehicle's identifier in the history.
    #[arg(long, value_name = "ID")]
    vehicle: String,
    /// The history database (SQLite; created if missing).
    ///
    /// The replay starts from the vehicle's last recorded parameters in it
    /// (else --theta0); each drive's write-back decision is logged in its
    /// table `decisions`, each written update in `calibrations`. A drive
    /// followed before for the vehicle is skipped.
    #[arg(long, value_name = "FILE")]
    db: PathBuf,
    /// Write each written update to this parameter file (.yaml, .json).
    #[arg(long, value_name = "FILE")]
    params_out: Option<PathBuf>,
    /// Write the per-drive report as JSON ("-": stdout).
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
    /// θ_0 when the history holds none: c_e,c_d,t_r,d (SI) or a parameter file.
    #[arg(long, allow_hyphen_values = true)]
    theta0: Option<ThetaArg>,
    /// Informative driving (s) over which θ must stay within one σ before
    /// an update is written.
    #[arg(long, default_value_t = 10.0, value_name = "S")]
    steady_s: f64,
    /// Weight of one segment's normal equations [default: 0.005].
    ///
    /// Smaller values make the estimate average over more segments
    /// (steadier, slower to follow a change).
    #[arg(long, value_name = "F")]
    information_scale: Option<f64>,
    /// Fold only segments whose peak yaw rate exceeds this, rad/s [default: 0, every segment].
    #[arg(long, value_name = "RAD_PER_S")]
    min_yaw_rate: Option<f64>,
}

/// The parameters in use: θ, its σ, and where they came from.
struct Stored {
    theta: Theta,
    sigma: Option<Theta>,
    origin: String,
    /// A recorded calibration (else θ_0, an initial guess).
    calibrated: bool,
}

/// Replays the drives and writes what the gates pass.
pub fn run(a: FollowArgs, bars: &Bars) -> Result<()> {
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
    if !(a.steady_s.is_finite() && a.steady_s >= 0.0) {
        bail!("--steady-s must be a non-negative number of seconds, got {}", a.steady_s);
    }
    // A drive that is not there is named before the history is opened (and created).
    if let Some(p) = a.drive.iter().find(|p| !p.exists()) {
        bail!("{}: no such drive file", p.display());
    }
    let mut db = History::open(&a.db)?;
    let mut stored = starting_point(&db, &a)?;
    let gates = Gates { steady_s: a.steady_s, ..Gates::default() };
    let quiet_stdout = a.json.as_deref().is_some_and(odocal::output::is_stdout);
    if !quiet_stdout {
        println!("vehicle '{}': starting from {} ({})", a.vehicle, stored.theta, stored.origin);
    }
    let mut cal: Option<Calibrator> = None;
    let mut entries = Vec::with_capacity(a.drive.len());
    for path in &a.drive {
        let drive = Replay::open(path)?;
        let source = path.display().to_string();
        let fingerprint = drive.fingerprint()?;
        if db.has_decisions(&a.vehicle, &fingerprint)? {
            if !quiet_stdout {
                println!(
                    "{source}: already followed for vehicle '{}' (fingerprint {}…); skipped",
                    a.vehicle,
                    &fingerprint[..12]
                );
            }
            entries.push(json!({"source": source, "fingerprint": fingerprint, "already_recorded": true,
                "prequential_mean_position_error_m": null, "updates": []}));
            continue;
        }
        let c = match cal.as_mut() {
            Some(c) => c,
            None => cal.insert(calibrator(&a, &stored, drive.sample_time_s())?),
        };
        if (drive.sample_time_s() - c.sample_time_s()).abs() > 1e-9 {
            bail!("{source}: sample time differs from the first drive's");
        }
        c.set_stored(Some(stored.theta));
        bars.event(Progress::Stage { name: "following", total: drive.len() as u64 });
        let mut done = 0;
        drive.push(c, |n| {
            bars.event(Progress::Advance((n - done) as u64));
            done = n;
        })?;
        bars.finish();
        let decision = gates.decide(c, &stored.theta, stored.calibrated);
        let summary = c.drive_summary();
        let (t_start_s, t_end_s) = drive.time_span_s();
        let drive_time_s = t_end_s - t_start_s;
        db.record_decision(&Decision {
            vehicle: a.vehicle.clone(),
            fingerprint: fingerprint.clone(),
            source: source.clone(),
            drive_time_s,
            decision: decision.action.to_string(),
            reasons: decision.reasons.clone(),
            theta: decision.theta,
            sigma: Some(decision.sigma),
        })?;
        let (delta, _) = c.heading_offset();
        if decision.action == Action::Write {
            stored = write_back(&mut db, &a, &decision, (&source, &fingerprint), drive.time_span_s(), delta)?;
        }
        if !quiet_stdout {
            let e = summary.prequential_mean_position_error_m.map_or("-".into(), |e| format!("{e:.3} m"));
            println!(
                "{source}: prequential Ē_p {e} over {} validation segment(s), {} segment(s) folded; θ = {} ± {}; {}: {}",
                summary.validation_segments,
                summary.folded_segments,
                decision.theta,
                decision.sigma,
                decision.action,
                decision.reasons.join("; ")
            );
        }
        entries.push(json!({
            "source": source,
            "fingerprint": fingerprint,
            "prequential_mean_position_error_m": summary.prequential_mean_position_error_m,
            "stored_mean_position_error_m": summary.stored_mean_position_error_m,
            "validation_segments": summary.validation_segments,
            "folded_segments": summary.folded_segments,
            "samples": summary.samples,
            "heading_offset_rad": delta,
            "updates": [update_json(&decision, drive_time_s)],
        }));
    }
    if let Some(p) = &a.json {
        write_text(p, &serde_json::to_string_pretty(&json!({ "drives": entries }))?)?;
    }
    Ok(())
}

/// A drive to replay: a canonical CSV read as a stream (memory flat in its
/// length), or a manifest's streams imported whole.
enum Replay {
    Stream(DriveStream),
    Whole(Drive),
}

impl Replay {
    /// Opens the drive at `path`, printing what its reader warns about.
    fn open(path: &std::path::Path) -> Result<Replay> {
        if odocal::is_manifest_path(path) {
            return Ok(Replay::Whole(load_drive_with_scale(path)?.0));
        }
        let stream = DriveStream::open(path)?;
        for w in stream.warnings() {
            eprintln!("warning: {w}");
        }
        Ok(Replay::Stream(stream))
    }

    fn fingerprint(&self) -> Result<String> {
        Ok(match self {
            Replay::Stream(s) => s.fingerprint()?,
            Replay::Whole(d) => d.fingerprint(),
        })
    }

    fn sample_time_s(&self) -> f64 {
        match self {
            Replay::Stream(s) => s.sample_time_s(),
            Replay::Whole(d) => d.sample_time_s(),
        }
    }

    fn len(&self) -> usize {
        match self {
            Replay::Stream(s) => s.len(),
            Replay::Whole(d) => d.len(),
        }
    }

    /// The first and the last time stamp, s.
    fn time_span_s(&self) -> (f64, f64) {
        match self {
            Replay::Stream(s) => s.time_span_s(),
            Replay::Whole(d) => (d.t().first().copied().unwrap_or(0.0), d.t().last().copied().unwrap_or(0.0)),
        }
    }

    /// Pushes the drive as a new drive in chunks of [`CHUNK`] samples.
    fn push(&self, c: &mut Calibrator, each: impl FnMut(usize)) -> Result<()> {
        match self {
            Replay::Stream(s) => c.push_stream(s, CHUNK, each)?,
            Replay::Whole(d) => c.push_drive(d, CHUNK, each)?,
        }
        Ok(())
    }
}

/// The parameters to start from: the vehicle's most recent row in the
/// history, else `--theta0` (default θ_0).
fn starting_point(db: &History, a: &FollowArgs) -> Result<Stored> {
    Ok(match db.latest(&a.vehicle)? {
        Some(r) => Stored {
            theta: r.record.theta,
            sigma: r.record.sigma,
            origin: format!("history row {}", r.id),
            calibrated: true,
        },
        None => Stored {
            theta: a.theta0.as_ref().map_or(Theta::PAPER_INITIAL, |t| t.theta),
            sigma: None,
            origin: "θ_0".into(),
            calibrated: false,
        },
    })
}

/// The online calibrator for the first drive, with the command line's options.
fn calibrator(a: &FollowArgs, stored: &Stored, sample_time_s: f64) -> Result<Calibrator> {
    let mut opts = OnlineOptions::default();
    if let Some(f) = a.information_scale {
        opts.information_scale = f;
    }
    if let Some(r) = a.min_yaw_rate {
        opts.segments.min_peak_yaw_rate_rad_per_s = r;
    }
    Ok(Calibrator::new(stored.theta, stored.sigma, sample_time_s, opts)?)
}

/// Writes a passed update: a `calibrations` row and the parameter file
/// (atomically). Returns the new stored parameters.
fn write_back(
    db: &mut History,
    a: &FollowArgs,
    decision: &GateDecision,
    (source, fingerprint): (&str, &str),
    (t_start_s, t_end_s): (f64, f64),
    heading_offset_rad: f64,
) -> Result<Stored> {
    let rec = CalibrationRecord {
        sources: vec![source.to_string()],
        t_start_s,
        t_end_s,
        sigma: Some(decision.sigma),
        heading_offset_rad: Some(heading_offset_rad),
        ..CalibrationRecord::new(&a.vehicle, fingerprint, METHOD, decision.theta)
    };
    db.record(&rec)?;
    if let Some(p) = &a.params_out {
        let s = decision.sigma.to_array().map(Some);
        let mut f = ParamFile::from_theta(&decision.theta, s, source, METHOD);
        f.provenance.push(("fingerprint".into(), fingerprint.to_string()));
        write_text(p, &f.text_for(p)?).with_context(|| format!("--params-out {}", p.display()))?;
    }
    Ok(Stored { theta: decision.theta, sigma: Some(decision.sigma), origin: source.to_string(), calibrated: true })
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
