//! The library's error type.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// Everything that can go wrong in the odocal library.
///
/// Messages name the file, line, column, option or parameter concerned and,
/// where there is one, what to do about it.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A CSV file is malformed at a given place.
    #[error("{path}: line {line}{}: {reason}", column.as_ref().map(|c| format!(", column '{c}'")).unwrap_or_default())]
    Csv {
        /// The file.
        path: PathBuf,
        /// 1-based line number in the file (the header is line 1).
        line: u64,
        /// The column, when the problem is in one.
        column: Option<String>,
        /// What is wrong.
        reason: String,
    },
    /// Required columns are missing from a CSV header.
    #[error("{path}: missing column(s) {}; columns found: {}{}", missing.join(", "), found.join(", "),
        hint.as_ref().map(|h| format!(" ({h})")).unwrap_or_default())]
    MissingColumns {
        /// The file.
        path: PathBuf,
        /// The required columns that were not found.
        missing: Vec<String>,
        /// The columns that were found.
        found: Vec<String>,
        /// What probably went wrong (a wrong separator, say).
        hint: Option<String>,
    },
    /// One value of a drive column is unusable.
    #[error("{context}: column '{column}', sample {sample}: {reason}")]
    InvalidSample {
        /// Where the data came from (a path or a description).
        context: String,
        /// The column.
        column: String,
        /// 0-based sample index.
        sample: usize,
        /// What is wrong.
        reason: String,
    },
    /// The data are not usable as a drive (too short, empty, ...).
    #[error("{context}: {reason}")]
    InvalidDrive {
        /// Where the data came from (a path or a description).
        context: String,
        /// What is wrong.
        reason: String,
    },
    /// An option has a value outside its valid range.
    #[error("invalid option `{field}`: {reason}")]
    InvalidOption {
        /// The option (field) name.
        field: &'static str,
        /// What is wrong with it.
        reason: String,
    },
    /// Command-line flags that cannot be used as given (a flag of another
    /// method, a value a flag does not take); the message names the flags
    /// (`--batches applies to --method three-step only, …`).
    #[error("{0}")]
    InvalidFlags(String),
    /// A parameter vector is invalid (not finite, non-positive track width...).
    #[error("invalid parameters: {0}")]
    InvalidTheta(String),
    /// No segment was usable for the requested computation.
    #[error("no usable segments: {0}")]
    NoSegments(String),
    /// A value given as text (a parameter name, a method, a solver…) is not
    /// one of the accepted ones.
    #[error("invalid {what} '{input}': use {expected}")]
    Parse {
        /// What was being parsed (`"parameter"`, `"method"`, …).
        what: &'static str,
        /// The text given.
        input: String,
        /// The accepted values.
        expected: &'static str,
    },
    /// Parameters cannot be identified from the data.
    #[error("parameter(s) {} not observable from these data: {reason}", params.join(", "))]
    NotObservable {
        /// The names of the parameters that cannot be identified, in
        /// vector order.
        params: Vec<&'static str>,
        /// Why.
        reason: String,
    },
    /// A numerical method diverged or produced non-finite numbers.
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// A QP solver failed on a problem, or its options are invalid: what
    /// the solver said.
    #[error("QP solver: {0}")]
    Qp(String),
    /// The compensation QP of one segment could not be solved (docs/method.md §5).
    #[error("compensation of the segment at sample {segment_start} (linearization {linearization}): solver {solver}: {source}{}",
        fallback.as_ref().map(|(n, e)| format!("; fallback {n}: {e}")).unwrap_or_default())]
    Compensation {
        /// First sample of the segment.
        segment_start: usize,
        /// The linearization (1-based) whose QP failed.
        linearization: usize,
        /// The solver that failed.
        solver: &'static str,
        /// Its error (why the QP was not solved: infeasible, the iteration
        /// limit, a numerical failure, a malformed problem).
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
        /// The fallback solver and its error, when one was tried.
        fallback: Option<(&'static str, String)>,
    },
    /// A drive manifest is invalid.
    #[error("{path}: {reason}")]
    Manifest {
        /// The manifest file.
        path: PathBuf,
        /// What is wrong, naming the key.
        reason: String,
    },
    /// A parameter file (ROS 2 YAML or JSON, as `--params-out` writes) could
    /// not be read as one.
    #[error("{path}: {reason}")]
    ParamFile {
        /// The parameter file.
        path: PathBuf,
        /// What is wrong, naming the key.
        reason: String,
    },
    /// JSON (de)serialisation failed.
    #[error("{context}: {source}")]
    Json {
        /// What was being read or written.
        context: String,
        /// The underlying error.
        #[source]
        source: serde_json::Error,
    },
    /// An output path names a file the same command reads, or another of
    /// its outputs (the same canonical path, or the same inode).
    #[error("{role} {} is also {other}; writing it would destroy that file: give {role} another path", path.display())]
    PathCollision {
        /// The output as the user named it (`--json`, `--out`).
        role: String,
        /// Its path, as given.
        path: PathBuf,
        /// The role (and path) of the file it would overwrite.
        other: String,
    },
    /// The same drive (the same samples: [`crate::Drive::fingerprint`]) is
    /// given twice.
    #[error("{second} is the same drive as {first} (the same samples, fingerprint {}…): give each drive once; \
             a drive counted twice shrinks σ as if it were new data, and a copy of the calibration data is no \
             validation", fingerprint.get(..12).unwrap_or(fingerprint))]
    DuplicateDrive {
        /// The first drive, by role and name.
        first: String,
        /// The drive that repeats it.
        second: String,
        /// Their fingerprint.
        fingerprint: String,
    },
    /// The same data given twice under different fingerprints: imported
    /// another way (a manifest and a CSV, times shifted, values rounded),
    /// its samples agree with another drive's ([`crate::refuse_duplicates`]).
    #[error("{second} holds the same samples as {first} ({how}; fingerprints {}… and {}…: the same data read \
             another way): give each drive once; a drive counted twice shrinks σ as if it were new data, and a \
             copy of the calibration data is no validation",
            fingerprints.1.get(..12).unwrap_or(&fingerprints.1), fingerprints.0.get(..12).unwrap_or(&fingerprints.0))]
    SameSamples {
        /// The first drive, by role and name.
        first: String,
        /// The drive that repeats it.
        second: String,
        /// How their samples agree.
        how: String,
        /// The fingerprints of `first` and `second`.
        fingerprints: (String, String),
    },
    /// A drive shares samples with another given with it: a part of it,
    /// or a copy thinned to every n-th sample ([`crate::refuse_duplicates`]).
    #[error("{part} shares {} % of its samples with {whole} ({shared} of its {samples} moving samples, the \
             reference position and both wheel readings bit for bit: a part or a thinned copy of it): held-out \
             data must be a different drive, and drives calibrated together must not overlap; give each stretch \
             of driving once", percent(*shared, *samples))]
    SharedSamples {
        /// The drive whose samples the other holds, by role and name.
        part: String,
        /// The drive that holds them.
        whole: String,
        /// How many of `part`'s samples `whole` holds.
        shared: usize,
        /// How many samples of `part` were compared (moving, once in it).
        samples: usize,
    },
    /// A ROS 2 bag has no topic of the requested name.
    #[error("{path}: no topic '{topic}' in the bag; its topics: {}", fmt_topics(available))]
    BagTopicNotFound {
        /// The bag file.
        path: PathBuf,
        /// The topic asked for.
        topic: String,
        /// The bag's topics with their message types, sorted by topic.
        available: Vec<(String, String)>,
    },
    /// A bag topic's message type is not one odocal reads.
    #[error("{path}: topic '{topic}' has message type '{found}', which odocal cannot read; supported types: {}", supported.join(", "))]
    BagMessageType {
        /// The bag file.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// Its message type (schema name), `(no schema)` when it has none.
        found: String,
        /// The types odocal reads.
        supported: Vec<&'static str>,
    },
    /// A column was asked for that the topic's message type does not have.
    #[error("{path}: topic '{topic}' ({message_type}) has no column '{column}'; valid columns: {}", valid.join(", "))]
    BagColumn {
        /// The bag file.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// The topic's message type.
        message_type: &'static str,
        /// The column asked for.
        column: String,
        /// The columns of that type.
        valid: Vec<String>,
    },
    /// A `sensor_msgs/msg/JointState` message does not name a requested joint.
    #[error("{path}: topic '{topic}': no joint named '{joint}' in message {index} (log time {} s); joint names present: {}", fmt_ns(*log_time_ns), present.join(", "))]
    BagJoint {
        /// The bag file.
        path: PathBuf,
        /// The topic.
        topic: String,
        /// The joint asked for.
        joint: String,
        /// 0-based index of the message within the topic, in file order.
        index: u64,
        /// The message's log time (ns since the epoch).
        log_time_ns: u64,
        /// The joint names the message has.
        present: Vec<String>,
    },
    /// A ROS 2 bag in sqlite3 storage (`.db3`), which odocal does not read.
    #[error("{path}: a ROS 2 sqlite3 (.db3) bag; odocal reads MCAP bags: convert it with `ros2 bag convert -i BAG -o out.yaml`, out.yaml being `output_bags: [{{uri: BAG_mcap, storage_id: mcap, all_topics: true}}]`")]
    BagSqlite {
        /// The `.db3` file or the bag directory.
        path: PathBuf,
    },
    /// A bag file is not MCAP, is corrupt or truncated, or a message does
    /// not decode.
    #[error("{path}{}: {reason}", topic.as_ref().map(|t| format!(": topic '{t}'")).unwrap_or_default())]
    Bag {
        /// The bag file.
        path: PathBuf,
        /// The topic, when the problem is in one.
        topic: Option<String>,
        /// What is wrong.
        reason: String,
    },
    /// The vehicle history database could not be opened, migrated, read or
    /// written (the crate odocal-history).
    #[error("{path}: history database: {reason}")]
    History {
        /// The database file.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
}

/// Nanoseconds as exact decimal seconds: `1720717537428161000` →
/// `1720717537.428161000`.
pub(crate) fn fmt_ns(ns: u64) -> String {
    format!("{}.{:09}", ns / 1_000_000_000, ns % 1_000_000_000)
}

/// `shared` of `samples` in whole percent, 100 only when all are shared.
fn percent(shared: usize, samples: usize) -> String {
    let p = 100.0 * shared as f64 / samples.max(1) as f64;
    if shared >= samples {
        "100".into()
    } else {
        format!("{:.0}", p.min(99.0))
    }
}

/// `/a (type), /b (type)` for the topic-not-found message.
fn fmt_topics(topics: &[(String, String)]) -> String {
    if topics.is_empty() {
        return "none".to_string();
    }
    topics.iter().map(|(t, ty)| format!("{t} ({ty})")).collect::<Vec<_>>().join(", ")
}

impl Error {
    /// An I/O error on `path`. The OS message is kept once (not repeated in
    /// the source chain when printed with `{:#}`).
    pub(crate) fn io(path: &std::path::Path, source: std::io::Error) -> Error {
        Error::Io { path: path.to_path_buf(), source }
    }
}

impl From<QpError> for Error {
    fn from(e: QpError) -> Error {
        Error::Qp(e.to_string())
    }
}

/// The library's result type.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Why a QP was not solved (in [`Error::Qp`] and [`Error::Compensation`]
/// as what the solver said).
#[derive(Debug, Clone, PartialEq, thiserror::Error, Serialize, Deserialize)]
pub(crate) enum QpError {
    /// The problem has no feasible point.
    #[error("infeasible: {0}")]
    Infeasible(String),
    /// The iteration limit was reached before convergence.
    #[error("iteration limit reached after {iterations} iterations (residual {residual:.2e})")]
    MaxIterations {
        /// Iterations taken.
        iterations: usize,
        /// Residual at the last iterate.
        residual: f64,
    },
    /// A numerical failure (factorisation, non-finite values).
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// The problem data are inconsistent.
    #[error("malformed problem: {0}")]
    Malformed(String),
}
