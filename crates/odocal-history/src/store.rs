//! The history's inserts on a connection or a transaction, and the
//! read-only connection of [`crate::History::open_read_only`].

use std::path::Path;

use rusqlite::{params, Connection};

use odocal::{Error, Result};

use crate::{sigma_params, sql_err, CalibrationRecord, DecisionRow, Recorded, BUSY_TIMEOUT, NOW};

/// A read-only connection to `path` and its schema version. A file in WAL
/// mode needs its `-shm` file to be read; in a folder the reader cannot
/// create it in (another user's history), the file is read as immutable
/// instead: as it is at the moment, without the WAL of a writer at work.
pub(crate) fn read_only_connection(path: &Path) -> rusqlite::Result<(Connection, i64)> {
    use rusqlite::OpenFlags;
    let flags = OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let open = |conn: rusqlite::Result<Connection>| -> rusqlite::Result<(Connection, i64)> {
        let conn = conn?;
        conn.busy_timeout(BUSY_TIMEOUT)?;
        let version = conn.query_row("PRAGMA user_version", [], |r| r.get(0))?;
        Ok((conn, version))
    };
    match open(Connection::open_with_flags(path, flags)) {
        Err(rusqlite::Error::SqliteFailure(e, _))
            if matches!(e.code, rusqlite::ErrorCode::ReadOnly | rusqlite::ErrorCode::CannotOpen) =>
        {
            use std::os::unix::ffi::OsStrExt;
            // A URI: every byte but the unreserved ones and `/` escaped.
            let mut uri = String::from("file:");
            for &b in path.as_os_str().as_bytes() {
                if b.is_ascii_alphanumeric() || b"-._~/".contains(&b) {
                    uri.push(char::from(b));
                } else {
                    uri.push_str(&format!("%{b:02X}"));
                }
            }
            uri.push_str("?immutable=1");
            open(Connection::open_with_flags(uri, flags | OpenFlags::SQLITE_OPEN_URI))
        }
        other => other,
    }
}

/// Inserts a calibration on `conn` (a connection or a transaction): [`crate::History::record`].
pub(crate) fn insert_record(conn: &Connection, path: &Path, rec: &CalibrationRecord) -> Result<Recorded> {
    rec.check()?;
    let err = sql_err(path);
    let sources = serde_json::to_string(&rec.sources)
        .map_err(|e| Error::History { path: path.to_path_buf(), reason: format!("source names: {e}") })?;
    let s = <[_; 4]>::from(rec.sigma);
    let n = conn
        .execute(
            &format!(
                "INSERT INTO calibrations (vehicle, recorded_at, fingerprint, sources, t_start_s, t_end_s, method, \
                 c_e, c_d, t_r, d, sigma_c_e, sigma_c_d, sigma_t_r, sigma_d, heading_offset_rad, verdict, \
                 odocal_version, sigma_model_only, held, unobservable, reasons, source_digest) VALUES (?1, {NOW}, \
                 ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18, ?19, ?20, ?21, ?22) \
                 ON CONFLICT (vehicle, fingerprint, method) DO NOTHING"
            ),
            params![
                rec.vehicle,
                rec.fingerprint,
                sources,
                rec.t_start_s,
                rec.t_end_s,
                rec.method,
                rec.theta.c_e,
                rec.theta.c_d,
                rec.theta.t_r,
                rec.theta.d,
                s[0],
                s[1],
                s[2],
                s[3],
                rec.heading_offset_rad,
                rec.verdict,
                env!("CARGO_PKG_VERSION"),
                rec.sigma_model_only,
                rec.held.join(","),
                rec.unobservable.join(","),
                rec.reasons.as_ref().map(|k| k.join(",")),
                rec.source_digest,
            ],
        )
        .map_err(&err)?;
    if n == 1 {
        return Ok(Recorded::New(conn.last_insert_rowid()));
    }
    let id = conn
        .query_row(
            "SELECT id FROM calibrations WHERE vehicle = ?1 AND fingerprint = ?2 AND method = ?3",
            params![rec.vehicle, rec.fingerprint, rec.method],
            |r| r.get(0),
        )
        .map_err(&err)?;
    Ok(Recorded::AlreadyRecorded(id))
}

/// Inserts a decision on `conn` (a connection or a transaction): [`crate::History::record_followed`].
pub(crate) fn insert_decision(conn: &Connection, path: &Path, d: &DecisionRow) -> Result<Option<i64>> {
    let err = sql_err(path);
    let reasons = serde_json::to_string(&d.reasons)
        .map_err(|e| Error::History { path: path.to_path_buf(), reason: format!("reasons: {e}") })?;
    let s = sigma_params(&d.sigma);
    let n = conn
        .execute(
            &format!(
                "INSERT INTO decisions (vehicle, decided_at, fingerprint, source, drive_time_s, decision, \
                 reasons, c_e, c_d, t_r, d, sigma_c_e, sigma_c_d, sigma_t_r, sigma_d, odocal_version, \
                 source_digest, t_start_s, clock_start_s) \
                 SELECT ?1, {NOW}, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16, ?17, ?18 \
                 WHERE NOT EXISTS (SELECT 1 FROM decisions WHERE vehicle = ?1 AND fingerprint = ?2)"
            ),
            params![
                d.vehicle,
                d.fingerprint,
                d.source,
                d.drive_time_s,
                d.decision,
                reasons,
                d.theta.c_e,
                d.theta.c_d,
                d.theta.t_r,
                d.theta.d,
                s[0],
                s[1],
                s[2],
                s[3],
                env!("CARGO_PKG_VERSION"),
                d.source_digest,
                d.t_start_s,
                d.clock_start_s,
            ],
        )
        .map_err(&err)?;
    Ok((n == 1).then(|| conn.last_insert_rowid()))
}
