//! `odocal history`: a vehicle's recorded calibrations, drift flags and a
//! pooled estimate; and the recording of `calibrate --vehicle --db`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use odocal::{CalibrationReport, Drive};
use odocal_history::{CalibrationRecord, History, Recorded};

use crate::output::{write_text, Files};

/// Arguments of `odocal history`.
#[derive(Args)]
pub struct HistoryArgs {
    /// The vehicle's identifier (as given to --vehicle).
    vehicle: String,
    /// The history database (SQLite).
    #[arg(long)]
    db: PathBuf,
    /// Pool only these rows (ids, comma separated) [default: all]; of
    /// several rows of one drive, the most recent given counts.
    #[arg(long, value_delimiter = ',', value_name = "IDS")]
    pool: Option<Vec<i64>>,
    /// Write the rows, drift flags and pooled estimate as JSON ("-": stdout).
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write a self-contained HTML page: each parameter over the recorded
    /// calibrations with ±σ bars and the drift flags marked, and the tables.
    #[arg(long, value_name = "FILE.html")]
    report: Option<PathBuf>,
}

/// Prints (or writes as JSON) the vehicle's history.
pub fn run(a: HistoryArgs) -> Result<()> {
    if !a.db.exists() {
        anyhow::bail!("{}: no such history database", a.db.display());
    }
    let mut files = Files::default();
    files
        .input("the history database", &a.db)
        .output("--json", a.json.as_deref())
        .output("--report", a.report.as_deref());
    files.check()?;
    // A read: the file is neither created, migrated nor changed.
    let db = History::open_read_only(&a.db)?;
    let h = db.vehicle(&a.vehicle, a.pool.as_deref())?;
    if h.rows.is_empty() && h.decisions.is_empty() {
        let known = db.vehicles()?;
        let echo = |v: &str| format!("'{}'", v.escape_debug());
        anyhow::bail!(
            "no vehicle '{}' in {}: {}",
            a.vehicle.escape_debug(),
            a.db.display(),
            if known.is_empty() {
                "it holds no calibrations (record some with calibrate --vehicle NAME --db FILE, or follow)".to_string()
            } else {
                let more = known.len().saturating_sub(20);
                let names = known.iter().take(20).map(|v| echo(v)).collect::<Vec<_>>().join(", ");
                let more = if more > 0 { format!(" and {more} more") } else { String::new() };
                format!("the vehicles it holds are {names}{more}")
            }
        );
    }
    if let Some(ids) = &a.pool {
        let missing: Vec<String> =
            ids.iter().filter(|id| !h.rows.iter().any(|r| r.id == **id)).map(i64::to_string).collect();
        if !missing.is_empty() {
            let held: Vec<String> = h.rows.iter().map(|r| r.id.to_string()).collect();
            anyhow::bail!(
                "--pool: vehicle '{}' has no row {} in {}; its rows are {}",
                a.vehicle.escape_debug(),
                missing.join(", "),
                a.db.display(),
                if held.is_empty() { "none".to_string() } else { held.join(", ") }
            );
        }
    }
    if let Some(p) = &a.report {
        let html = odocal_report::history::render_history_html(&h)?;
        write_text(p, &html).with_context(|| format!("--report {}", p.display()))?;
        if !crate::output::is_stdout(p) {
            eprintln!("wrote {}", p.display());
        }
    }
    if let Some(p) = &a.json {
        let v = serde_json::json!({
            "vehicle": a.vehicle,
            "rows": h.rows,
            "set_aside": h.set_aside,
            "drift": h.drift,
            "pooled": h.pooled,
        });
        write_text(p, &serde_json::to_string_pretty(&v)?)?;
    }
    // An output on stdout (`--report -`, `--json -`) is stdout's alone.
    if files.any_stdout() {
        return Ok(());
    }
    if h.rows.is_empty() {
        println!("no calibrations of vehicle '{}' in {}", a.vehicle, a.db.display());
        return Ok(());
    }
    print!("{h}");
    Ok(())
}

/// Refuses a `--db` that cannot be a history written to (`-`, a device,
/// a file that is no history database, one that cannot be written), before
/// any work: opened (and migrated) when it exists; a new file is created
/// when the calibration is recorded.
pub fn check_db(db: &Path) -> Result<()> {
    crate::output::refuse_stdout("--db", db, "the history is a database file")?;
    if db.exists() {
        History::open_to_write(db)?;
    }
    Ok(())
}

/// Records a calibration in the vehicle's history (`calibrate --vehicle
/// --db`); says on stderr whether it was new or already recorded.
pub fn record_calibration(
    (vehicle, db): (&str, &Path),
    drive: &Drive,
    sources: &[PathBuf],
    fingerprint: &str,
    r: &CalibrationReport,
) -> Result<()> {
    let mut h = History::open_to_write(db)?;
    let t = drive.t();
    let span = (t.first().copied().unwrap_or(0.0), t.last().copied().unwrap_or(0.0));
    let names = sources.iter().map(|p| p.display().to_string()).collect();
    let mut rec = CalibrationRecord::of_report(vehicle, fingerprint, names, span, r);
    // The files' digests, by which `follow` and the pooled estimate know
    // the same data imported another way; none for a drive read from
    // standard input.
    rec.source_digest = odocal_history::source_digests(sources);
    // The history's errors name the file.
    match h.record(&rec)? {
        Recorded::New(id) => eprintln!("recorded in {} as row {id} of vehicle '{vehicle}'", db.display()),
        Recorded::AlreadyRecorded(id) => eprintln!(
            "already recorded: {} holds this drive calibrated by {} for vehicle '{vehicle}' (row {id}); nothing added",
            db.display(),
            r.method
        ),
    }
    Ok(())
}
