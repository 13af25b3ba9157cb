//! The history database's schema: an ordered list of migrations, the
//! schema version in SQLite's `PRAGMA user_version`.

use rusqlite::{Connection, TransactionBehavior};

/// The migrations, in order: migration `i` (0-based) takes the database
/// from schema version `i` to `i + 1`. A file with version 0 (new or empty)
/// runs all of them; one with a version above `MIGRATIONS.len()` was
/// written by a newer odocal and is refused.
pub(super) const MIGRATIONS: &[&str] = &[
    // Version 1: calibrations and write-back decisions.
    "CREATE TABLE calibrations (
        id INTEGER PRIMARY KEY,
        vehicle TEXT NOT NULL,
        recorded_at TEXT NOT NULL,
        fingerprint TEXT NOT NULL,
        sources TEXT NOT NULL,
        t_start_s REAL NOT NULL,
        t_end_s REAL NOT NULL,
        method TEXT NOT NULL,
        c_e REAL NOT NULL,
        c_d REAL NOT NULL,
        t_r REAL NOT NULL,
        d REAL NOT NULL,
        sigma_c_e REAL,
        sigma_c_d REAL,
        sigma_t_r REAL,
        sigma_d REAL,
        heading_offset_rad REAL,
        verdict TEXT,
        odocal_version TEXT NOT NULL
    );
    CREATE UNIQUE INDEX calibrations_drive ON calibrations (vehicle, fingerprint, method);
    CREATE INDEX calibrations_vehicle ON calibrations (vehicle, recorded_at);
    CREATE TABLE decisions (
        id INTEGER PRIMARY KEY,
        vehicle TEXT NOT NULL,
        decided_at TEXT NOT NULL,
        fingerprint TEXT NOT NULL,
        source TEXT NOT NULL,
        drive_time_s REAL NOT NULL,
        decision TEXT NOT NULL,
        reasons TEXT NOT NULL,
        c_e REAL NOT NULL,
        c_d REAL NOT NULL,
        t_r REAL NOT NULL,
        d REAL NOT NULL,
        sigma_c_e REAL,
        sigma_c_d REAL,
        sigma_t_r REAL,
        sigma_d REAL,
        odocal_version TEXT NOT NULL
    );
    CREATE INDEX decisions_drive ON decisions (vehicle, fingerprint);",
    // Version 2: whether a row's σ is the model's alone (1), checked against
    // the data (0) or not known (NULL, rows recorded before the column).
    "ALTER TABLE calibrations ADD COLUMN sigma_model_only INTEGER;",
    // Version 3: the parameters held at θ_0 and those named not observable
    // (comma-separated names; NULL for rows recorded before the columns:
    // not known). A row of `follow` holds an update every write-back gate
    // passed, the verdict its parameter file gives.
    "ALTER TABLE calibrations ADD COLUMN held TEXT;
    ALTER TABLE calibrations ADD COLUMN unobservable TEXT;
    UPDATE calibrations SET verdict = 'accepted' WHERE method = 'online' AND verdict IS NULL;",
    // Version 4: the verdict's reason kinds (comma-separated, e.g.
    // `input_noise_bias,model_sigma_only`; empty for none; NULL for rows
    // recorded before the column: not known).
    "ALTER TABLE calibrations ADD COLUMN reasons TEXT;",
    // Version 5: the drives' source digests (a hash of the files read, one
    // per drive, comma-separated) and a decision's first sample time, so
    // the same data imported another way is known; NULL for rows recorded
    // before the columns: not known.
    "ALTER TABLE calibrations ADD COLUMN source_digest TEXT;
    ALTER TABLE decisions ADD COLUMN source_digest TEXT;
    ALTER TABLE decisions ADD COLUMN t_start_s REAL;",
    // Version 6: a decision's drive's first stamp on the logger's clock
    // when that clock reads as Unix time, so a later `follow` run can tell
    // a drive recorded before the last one followed; NULL when the clock
    // says nothing about order or for rows recorded before the column.
    "ALTER TABLE decisions ADD COLUMN clock_start_s REAL;",
];

/// The schema version this odocal writes.
pub(super) const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

/// Refuses a schema version above this odocal's: the file was written by
/// a newer odocal. `Err` holds the reason.
pub(super) fn check_not_newer(version: i64) -> Result<(), String> {
    if version > SCHEMA_VERSION {
        return Err(format!(
            "schema version {version} is newer than this odocal's ({SCHEMA_VERSION}): use a newer odocal"
        ));
    }
    Ok(())
}

/// What the history's opening finds in an SQLite file before it changes
/// anything.
pub(super) enum Found {
    /// A new or empty database (no tables, schema version 0): a history
    /// is created in it.
    Empty,
    /// A history: the tables `calibrations` and `decisions` and a schema
    /// version from 1 to [`SCHEMA_VERSION`].
    History,
    /// Not an odocal history; the reason names what it holds.
    Foreign(String),
}

/// Looks at the file on `conn` without changing it: its schema version,
/// its `application_id` (odocal sets none) and the tables it holds, read
/// in one transaction, so that another process creating the history at
/// the same moment is seen before or after its migration, never between
/// its tables and its schema version.
pub(super) fn inspect(conn: &Connection) -> rusqlite::Result<Found> {
    let tx = conn.unchecked_transaction()?;
    let found = inspect_in(&tx);
    tx.commit()?;
    found
}

fn inspect_in(conn: &Connection) -> rusqlite::Result<Found> {
    let version: i64 = conn.query_row("PRAGMA user_version", [], |r| r.get(0))?;
    let application_id: i64 = conn.query_row("PRAGMA application_id", [], |r| r.get(0))?;
    let mut st = conn.prepare(
        "SELECT name FROM sqlite_master WHERE type IN ('table', 'view') AND name NOT LIKE 'sqlite\\_%' ESCAPE '\\' \
         ORDER BY name",
    )?;
    let tables = st.query_map([], |r| r.get::<_, String>(0))?.collect::<rusqlite::Result<Vec<String>>>()?;
    let has = |name: &str| tables.iter().any(|t| t == name);
    // Names from the file, echoed escaped and cut.
    let named = || {
        let shown: Vec<String> = tables.iter().take(5).map(|t| format!("'{}'", cut(t))).collect();
        let more = tables.len().saturating_sub(5);
        let more = if more > 0 { format!(" and {more} more") } else { String::new() };
        format!("{}{more}", shown.join(", "))
    };
    Ok(if application_id != 0 {
        Found::Foreign(format!("an SQLite file of another application (application_id {application_id:#x})"))
    } else if version == 0 && tables.is_empty() {
        Found::Empty
    } else if version == 0 {
        Found::Foreign(format!("an SQLite file of another application (its tables: {})", named()))
    } else if version > SCHEMA_VERSION {
        // The schema version of a newer odocal's, refused by its own message.
        Found::History
    } else if has("calibrations") && has("decisions") {
        Found::History
    } else {
        let held = if tables.is_empty() { "no tables".to_string() } else { format!("its tables: {}", named()) };
        Found::Foreign(format!(
            "an SQLite file of schema version {version} without a history's tables calibrations and decisions \
             ({held}): another application's file, or a damaged history"
        ))
    })
}

/// A name read from a file as a message shows it: control characters
/// escaped, at most 40 characters.
fn cut(name: &str) -> String {
    let mut s: String = name.chars().take(40).collect::<String>().escape_debug().to_string();
    if name.chars().count() > 40 {
        s.push('…');
    }
    s
}

/// Brings the database to [`SCHEMA_VERSION`], each migration in its own
/// immediate transaction (so two processes opening a new file at once
/// migrate it once). A migration that fails says the file is not an
/// odocal history or a damaged one. `Err` holds the reason.
pub(super) fn migrate(conn: &mut Connection) -> Result<(), String> {
    loop {
        let tx = conn.transaction_with_behavior(TransactionBehavior::Immediate).map_err(|e| e.to_string())?;
        let version: i64 = tx.query_row("PRAGMA user_version", [], |r| r.get(0)).map_err(|e| e.to_string())?;
        check_not_newer(version)?;
        if version == SCHEMA_VERSION {
            return Ok(());
        }
        // `version` is in 0..SCHEMA_VERSION here.
        let sql = MIGRATIONS[version as usize];
        tx.execute_batch(sql).map_err(|e| {
            format!(
                "migration to schema version {} failed ({e}): not an odocal history of schema version {version}, \
                 or a damaged one",
                version + 1
            )
        })?;
        tx.pragma_update(None, "user_version", version + 1).map_err(|e| e.to_string())?;
        tx.commit().map_err(|e| e.to_string())?;
    }
}
