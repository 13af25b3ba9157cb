//! `odocal history`: a vehicle's recorded calibrations, drift flags and a
//! pooled estimate; and the recording of `calibrate --vehicle --db`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use odocal::history::{CalibrationRecord, History, HistoryRow, Recorded};
use odocal::{CalibrationReport, Drive};

use crate::output::{write_text, Files};

/// Arguments of `odocal history`.
#[derive(Args)]
pub struct HistoryArgs {
    /// The vehicle's identifier (as given to --vehicle).
    vehicle: String,
    /// The history database (SQLite).
    #[arg(long)]
    db: PathBuf,
    /// Pool only these rows (ids, comma separated) [default: all].
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
    let db = History::open(&a.db)?;
    let rows = db.rows(&a.vehicle)?;
    let drift = odocal::history::drift_between(&db.rows(&a.vehicle)?);
    let pooled = db.pooled(&a.vehicle, a.pool.as_deref())?;
    if let Some(p) = &a.report {
        let html = odocal_report::history::render_history_html(&a.vehicle, &rows, &drift, pooled.as_ref())?;
        if odocal::output::is_stdout(p) {
            if a.json.as_deref().is_some_and(odocal::output::is_stdout) {
                anyhow::bail!("--report - and --json -: only one of them can go to stdout");
            }
            write_text(p, &html)?;
            return Ok(());
        }
        write_text(p, &html).with_context(|| format!("--report {}", p.display()))?;
        eprintln!("wrote {}", p.display());
    }
    if let Some(p) = &a.json {
        let v = serde_json::json!({
            "vehicle": a.vehicle,
            "rows": rows,
            "drift": drift,
            "pooled": pooled,
        });
        write_text(p, &serde_json::to_string_pretty(&v)?)?;
        if odocal::output::is_stdout(p) {
            return Ok(());
        }
    }
    if rows.is_empty() {
        println!("no calibrations of vehicle '{}' in {}", a.vehicle, a.db.display());
        return Ok(());
    }
    print!("{}", table(&rows));
    if drift.is_empty() {
        println!("\nno drift: consecutive rows agree within 3 combined σ");
    } else {
        println!("\ndrift (|Δ| > 3·sqrt(σ₁² + σ₂²)):");
        for f in &drift {
            println!(
                "  {} row {} ({}) → row {} ({}): {:+.4e} (combined σ {:.2e}, {:.1}σ)",
                f.parameter,
                f.from_id,
                f.from_recorded_at,
                f.to_id,
                f.to_recorded_at,
                f.change,
                f.combined_sigma,
                f.change.abs() / f.combined_sigma
            );
        }
    }
    if let Some(p) = pooled {
        println!("\npooled over {} row(s) (inverse-variance mean ± its σ; between-drive sd):", p.rows);
        let (m, s, b) = (p.mean.to_array(), p.sigma_of_mean.to_array(), p.between_drive_sd.to_array());
        for (i, name) in odocal::model::THETA_NAMES.iter().enumerate() {
            // One row has no spread between drives.
            let sd = if b[i].is_finite() { format!("{:.2e}", b[i]) } else { "— (needs two rows)".into() };
            println!("  {name:<4} {:>12.6} ± {:.2e}   between-drive sd {sd}", m[i], s[i]);
        }
    }
    Ok(())
}

/// The rows as a text table, one row per recorded drive and method.
fn table(rows: &[HistoryRow]) -> String {
    let mut out = format!(
        "{:>4}  {:<24} {:<10} {:>10} {:>11} {:>9} {:>10}  {:<9} {}\n",
        "id", "recorded (UTC)", "method", "c_e", "c_d", "t_r", "d", "verdict", "source"
    );
    for r in rows {
        let c = &r.record;
        let sd = c.sigma.map(|s| s.to_array());
        let cell = |i: usize, v: f64, digits: usize| match sd {
            Some(s) => format!("{v:.digits$}±{:.1e}", s[i]),
            None => format!("{v:.digits$}"),
        };
        out.push_str(&format!(
            "{:>4}  {:<24} {:<10} {} {} {} {}  {:<9} {}\n",
            r.id,
            r.recorded_at,
            c.method,
            cell(0, c.theta.c_e, 5),
            cell(1, c.theta.c_d * 1e3, 3) + "mm",
            cell(2, c.theta.t_r, 3),
            cell(3, c.theta.d * 1e3, 3) + "mm/g",
            c.verdict.as_deref().unwrap_or("-"),
            c.sources.join(", ")
        ));
    }
    out
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
    let mut h = History::open(db)?;
    let t = drive.t();
    let span = (t.first().copied().unwrap_or(0.0), t.last().copied().unwrap_or(0.0));
    let names = sources.iter().map(|p| p.display().to_string()).collect();
    let rec = CalibrationRecord::of_report(vehicle, fingerprint, names, span, r);
    match h.record(&rec).with_context(|| format!("recording in {}", db.display()))? {
        Recorded::New(id) => eprintln!("recorded in {} as row {id} of vehicle '{vehicle}'", db.display()),
        Recorded::AlreadyRecorded(id) => eprintln!(
            "already recorded: {} holds this drive calibrated by {} for vehicle '{vehicle}' (row {id}); nothing added",
            db.display(),
            r.method
        ),
    }
    Ok(())
}
