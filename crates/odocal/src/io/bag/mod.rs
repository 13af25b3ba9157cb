//! ROS 2 bags (MCAP storage, CDR messages) read as tables of numbers.
//!
//! A bag topic becomes a [`Table`]: a time vector plus named numeric columns,
//! the same shape as a CSV stream, so the import pipeline can treat both
//! alike. [`read_topic`] reads one topic; [`inspect`] lists what a bag holds,
//! like `ros2 bag info`. This module is behind the cargo feature `mcap`
//! (on by default).
//!
//! ## Columns
//!
//! | message type | columns |
//! |---|---|
//! | `sensor_msgs/msg/JointState` | `position.<joint name>` (rad), `velocity.<joint name>` (rad/s) |
//! | `geometry_msgs/msg/PoseWithCovarianceStamped` | `x`, `y`, `z` (m), `yaw` (rad), `cov_x`, `cov_y` (m²), `cov_yaw` (rad²) |
//! | `geometry_msgs/msg/PoseStamped` | `x`, `y`, `z`, `yaw` |
//! | `nav_msgs/msg/Odometry` | as PoseWithCovarianceStamped, plus `v_x` (m/s), `omega_z` (rad/s) from the twist |
//! | `sensor_msgs/msg/NavSatFix` | `latitude`, `longitude` (deg), `altitude` (m), `status` (`status.status`), `cov_e`, `cov_n`, `cov_u` (m²) |
//! | `sensor_msgs/msg/Imu` | `acc_x`, `acc_y`, `acc_z` (m/s²), `gyro_x`, `gyro_y`, `gyro_z` (rad/s) |
//!
//! - **Joints** are picked by name, so the caller chooses them by asking for
//!   the column: `position.rear_left_wheel_joint`. A message that does not
//!   name the joint is an error listing the names it has. Joint order may
//!   change between messages; each message is looked up by name.
//! - **yaw** is the rotation about z of the quaternion's ZYX decomposition,
//!   `atan2(2(wz + xy), 1 − 2(y² + z²))` in [−π, π]: counter-clockwise from
//!   the frame's x axis, i.e. from east in an ENU `map` frame (REP-103).
//! - **Covariances** are diagonal entries: `cov_x`, `cov_y`, `cov_yaw` are
//!   elements 0, 7 and 35 of the row-major 6×6 pose covariance over
//!   (x, y, z, roll, pitch, yaw); `cov_e`, `cov_n`, `cov_u` are elements 0, 4
//!   and 8 of NavSatFix's 3×3 ENU `position_covariance`.
//! - Asking for no columns (`&[]`) returns every column of the type; for
//!   `JointState`, position and velocity of the joints the first message
//!   names.
//!
//! ## Time
//!
//! [`TimeSource::HeaderStamp`] (the default) takes `header.stamp`; the
//! alternative [`TimeSource::LogTime`] takes the MCAP log time (when the
//! recorder received the message). Either becomes seconds since the epoch as
//! the `f64` nearest the exact decimal `sec.nanosec` (so it equals the same
//! time parsed from CSV text). Rows are sorted by that time; messages with
//! equal times keep their order in the file.
//!
//! ## What is refused
//!
//! Every error names the file and, where there is one, the topic: an unknown
//! topic (listing the bag's topics and types), a message type odocal does not
//! read (listing those it does), an unknown column (listing the valid ones),
//! a missing joint, a message that is not valid CDR, a corrupt or truncated
//! file, and a ROS 2 sqlite3 bag (`.db3`, or a bag directory holding one),
//! with the `ros2 bag convert` command that turns it into MCAP. A bag
//! directory holding exactly one `.mcap` file is read as that file.
//!
//! Memory stays bounded on hostile input: records and decompressed chunks are
//! capped (see `MAX_RECORD_BYTES`), a topic may not hold more messages than
//! the file has bytes, and malformed CDR is an error, never a panic.
//!
//! ## Example
//!
//! ```no_run
//! # fn main() -> Result<(), odocal::Error> {
//! use odocal::io::bag::{self, TimeSource};
//! use std::path::Path;
//!
//! let path = Path::new("drive.mcap");
//! println!("{}", bag::inspect(path)?); // topics, types, counts, rates
//! let wheels = bag::read_topic(
//!     path,
//!     "/vehicle/wheel_joint_states",
//!     &["position.rear_left_wheel_joint", "position.rear_right_wheel_joint"],
//!     TimeSource::HeaderStamp,
//! )?;
//! let left = &wheels.columns["position.rear_left_wheel_joint"];
//! println!("{} rows from {}; last left wheel angle {:?} rad", wheels.t_s.len(), wheels.source, left.last());
//! # Ok(()) }
//! ```

mod columns;
mod decompress;
mod draft;
mod msg;
mod records;
#[cfg(test)]
mod tests;

use columns::{Column, Decoded, JointField, MessageType};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt;
use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use crate::error::{fmt_ns, Error, Result};

/// The largest record or decompressed chunk odocal accepts, in bytes: a
/// corrupt length field cannot make it allocate more. Real bags cut chunks at
/// about 1 MiB (rosbag2's default is 768 KiB); a single message larger than
/// this (a 256 MiB point cloud) is refused.
pub(crate) const MAX_RECORD_BYTES: usize = 256 << 20;

/// The first bytes of an SQLite 3 database, i.e. of a `.db3` bag.
const SQLITE_MAGIC: &[u8] = b"SQLite format 3\0";

/// One bag topic as columns of numbers, like a CSV stream.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Table {
    /// Time of each row (s since the epoch), non-decreasing; from the header
    /// stamp or the log time, see [`TimeSource`].
    pub t_s: Vec<f64>,
    /// The requested columns by name, each as long as `t_s`.
    pub columns: BTreeMap<String, Vec<f64>>,
    /// Where the rows came from: `path:topic`, e.g. `drive.mcap:/vehicle/wheel_joint_states`.
    pub source: String,
}

impl Table {
    /// The joints of a `JointState` table that have a `field` column
    /// (`"position"` or `"velocity"`: the names in `field.<joint>`), sorted.
    pub(crate) fn joints(&self, field: &str) -> Vec<&str> {
        self.columns.keys().filter_map(|k| k.strip_prefix(field)?.strip_prefix('.')).collect()
    }
}

/// Which clock a [`Table`]'s times come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TimeSource {
    /// `header.stamp` of each message: when the data were measured, on the
    /// publisher's clock (the default).
    #[default]
    HeaderStamp,
    /// The MCAP log time: when the recorder received the message.
    LogTime,
}

/// Reads the columns `columns` of topic `topic` from the MCAP bag at `path`.
///
/// See the [module docs](self) for the column names of each message type and
/// the time conventions. `columns` empty means every column of the type.
///
/// # Errors
/// [`Error::BagTopicNotFound`], [`Error::BagMessageType`],
/// [`Error::BagColumn`], [`Error::BagJoint`], [`Error::BagSqlite`], and
/// [`Error::Bag`] for a file that is not MCAP, is corrupt or truncated, a
/// topic without messages, or a message that does not decode.
pub fn read_topic(path: impl AsRef<Path>, topic: &str, columns: &[&str], time: TimeSource) -> Result<Table> {
    let path = path.as_ref();
    read(path, topic, columns, time, false)
}

/// The joint names of the first message of the `JointState` topic `topic`
/// (those with a position or a velocity), sorted: the names a manifest's
/// `position.<joint>` / `velocity.<joint>` columns take. Reads up to that
/// message only. A topic of another type has none (an empty list).
///
/// # Errors
/// As [`read_topic`].
pub(crate) fn joint_names(path: &Path, topic: &str) -> Result<Vec<String>> {
    let table = first_message(path, topic)?;
    let names: BTreeSet<&str> = table.joints("position").into_iter().chain(table.joints("velocity")).collect();
    Ok(names.into_iter().map(str::to_string).collect())
}

/// The first message of a `JointState` topic as a one-row table of every
/// joint's position and velocity.
pub(crate) fn first_message(path: &Path, topic: &str) -> Result<Table> {
    read(path, topic, &[], TimeSource::HeaderStamp, true)
}

/// [`read_topic`], stopping after the topic's first message when `first_only`.
fn read(path: &Path, topic: &str, columns: &[&str], time: TimeSource, first_only: bool) -> Result<Table> {
    let mut bag = Bag::open(path)?;
    let summary = bag.summary();
    let mut plan: Option<Plan> = None;
    if let Some(s) = &summary {
        // Fail before decompressing anything when the summary already says no.
        let chans: Vec<_> = s.channels.values().filter(|c| c.topic == topic).collect();
        if chans.is_empty() {
            return Err(Error::BagTopicNotFound {
                path: bag.path.clone(),
                topic: topic.to_string(),
                available: topic_list(s.channels.values().map(|c| c.as_ref())),
            });
        }
        for c in chans {
            let ty = channel_type(&bag.path, c)?;
            plan = Some(Plan::new(&bag.path, topic, ty, columns)?);
        }
    }
    let file_len = bag.len;
    let mut seen_topics: BTreeMap<u16, (String, String)> = BTreeMap::new();
    let mut types: HashMap<u16, MessageType> = HashMap::new();
    let mut out = Collect::default();
    let path_buf = bag.path.clone();
    bag.scan(summary.as_ref(), |m| {
        if m.channel.topic != topic {
            seen_topics.entry(m.channel.id).or_insert_with(|| (m.channel.topic.clone(), schema_name(&m.channel)));
            return Ok(ControlFlow::Continue(()));
        }
        let ty = match types.get(&m.channel.id) {
            Some(ty) => *ty,
            None => {
                let ty = channel_type(&path_buf, &m.channel)?;
                types.insert(m.channel.id, ty);
                ty
            }
        };
        if plan.is_none() {
            plan = Some(Plan::new(&path_buf, topic, ty, columns)?);
        }
        let Some(plan) = plan.as_mut() else { return Ok(ControlFlow::Continue(())) };
        if plan.ty != ty {
            let reason = format!("its channels carry two message types, {} and {ty}", plan.ty);
            return Err(bag_err(&path_buf, topic, reason));
        }
        if out.t_s.len() as u64 >= file_len {
            return Err(bag_err(
                &path_buf,
                topic,
                format!("more messages than the file has bytes ({file_len}): a corrupt or hostile file"),
            ));
        }
        out.push(&path_buf, topic, plan, m, time)?;
        Ok(if first_only { ControlFlow::Break(()) } else { ControlFlow::Continue(()) })
    })?;
    let Some(plan) = plan else {
        return Err(Error::BagTopicNotFound {
            path: bag.path.clone(),
            topic: topic.to_string(),
            available: {
                let mut v: Vec<_> = seen_topics.into_values().collect::<BTreeSet<_>>().into_iter().collect();
                v.sort();
                v
            },
        });
    };
    if out.t_s.is_empty() {
        return Err(bag_err(&bag.path, topic, format!("no messages ({})", plan.ty)));
    }
    clock_steps(&bag.path, topic, &out.t_s, time)?;
    Ok(out.finish(plan, format!("{}:{topic}", bag.path.display())))
}

/// What a bag holds, from [`inspect`]; its `Display` reads like
/// `ros2 bag info`.
#[derive(Debug, Clone, PartialEq)]
pub struct BagInfo {
    /// The MCAP file.
    pub path: PathBuf,
    /// File size (bytes).
    pub size_bytes: u64,
    /// The MCAP profile (`ros2` for ROS 2 bags).
    pub profile: String,
    /// The library that wrote the file.
    pub library: String,
    /// Chunk compression formats used (`zstd`, `lz4`, `none`), from the
    /// summary's chunk index; `None` when the file has no summary.
    pub compression: Option<Vec<String>>,
    /// Number of chunks, from the summary; `None` without one.
    pub chunk_count: Option<usize>,
    /// Messages in the file (all topics), counted by reading them.
    pub message_count: u64,
    /// Earliest log time (ns since the epoch); `None` for a bag without messages.
    pub start_log_time_ns: Option<u64>,
    /// Latest log time (ns since the epoch).
    pub end_log_time_ns: Option<u64>,
    /// One entry per topic, sorted by topic name.
    pub topics: Vec<TopicInfo>,
}

impl BagInfo {
    /// The columns a manifest's MCAP stream can take from each topic odocal
    /// reads (`  /topic: col, col, …`, names shown with
    /// [`crate::output::visible`]), under a heading; for a `JointState`
    /// topic also the joint names its columns need (those of its first
    /// message, which is read for them). Empty when no topic is readable.
    ///
    /// # Errors
    /// As [`read_topic`], reading a `JointState` topic's first message.
    pub fn manifest_columns(&self) -> Result<String> {
        use std::fmt::Write as _;
        let readable: Vec<_> = self.topics.iter().filter_map(|t| Some((t, t.supported_type?))).collect();
        if readable.is_empty() {
            return Ok(String::new());
        }
        let mut o = String::from("Manifest columns (format = \"mcap\", topic = ...):\n");
        for (t, ty) in readable {
            let _ = writeln!(o, "  {}: {}", crate::output::visible(&t.topic), ty.columns().join(", "));
            if ty == MessageType::JointState && t.count > 0 {
                let joints = joint_names(&self.path, &t.topic)?;
                let _ = writeln!(o, "    joints: {}", crate::output::visible(&joints.join(", ")));
            }
        }
        Ok(o)
    }

    /// Time from the first to the last message (s, log time); 0 without messages.
    pub(crate) fn duration_s(&self) -> f64 {
        match (self.start_log_time_ns, self.end_log_time_ns) {
            (Some(a), Some(b)) => ns_to_s(i128::from(b) - i128::from(a)),
            _ => 0.0,
        }
    }
}

/// One topic of a bag, in [`BagInfo`].
#[derive(Debug, Clone, PartialEq)]
pub struct TopicInfo {
    /// The topic name.
    pub topic: String,
    /// Its message type (schema name), `(no schema)` when it has none.
    pub message_type: String,
    /// The message encoding (`cdr` in ROS 2 bags).
    pub message_encoding: String,
    /// Number of messages.
    pub count: u64,
    /// First log time (ns since the epoch); `None` without messages.
    pub first_log_time_ns: Option<u64>,
    /// Last log time (ns since the epoch).
    pub last_log_time_ns: Option<u64>,
    /// The type as odocal reads it, `None` when [`read_topic`] cannot read
    /// it (another type, or an encoding other than `cdr`).
    pub(crate) supported_type: Option<MessageType>,
}

impl TopicInfo {
    /// Mean message rate (Hz) over the log times, `(count − 1) / (last − first)`;
    /// `None` with fewer than two messages or no time span.
    pub(crate) fn rate_hz(&self) -> Option<f64> {
        let (a, b) = (self.first_log_time_ns?, self.last_log_time_ns?);
        (self.count >= 2 && b > a).then(|| (self.count - 1) as f64 / ns_to_s(i128::from(b) - i128::from(a)))
    }
}

/// Lists the topics of the MCAP bag at `path`, with their types, message
/// counts, first and last log times and rates, and the file's compression.
///
/// It reads (and decompresses) every message, so it also checks that the
/// whole file is readable.
///
/// # Errors
/// [`Error::BagSqlite`] for a `.db3` bag, [`Error::Bag`] for a file that is
/// not MCAP or is corrupt or truncated.
pub fn inspect(path: impl AsRef<Path>) -> Result<BagInfo> {
    let path = path.as_ref();
    let mut bag = Bag::open(path)?;
    let (profile, library) = bag.header()?;
    let summary = bag.summary();
    let mut topics: BTreeMap<(String, String, String), TopicInfo> = BTreeMap::new();
    let key = |c: &mcap::Channel| (c.topic.clone(), schema_name(c), c.message_encoding.clone());
    let new_topic = |k: &(String, String, String)| TopicInfo {
        topic: k.0.clone(),
        message_type: k.1.clone(),
        message_encoding: k.2.clone(),
        count: 0,
        first_log_time_ns: None,
        last_log_time_ns: None,
        supported_type: if k.2 == "cdr" { MessageType::from_ros_name(&k.1) } else { None },
    };
    if let Some(s) = &summary {
        for c in s.channels.values() {
            let k = key(c);
            topics.entry(k.clone()).or_insert_with(|| new_topic(&k));
        }
    }
    let mut by_channel: HashMap<u16, (String, String, String)> = HashMap::new();
    let (mut count, mut start, mut end) = (0u64, None::<u64>, None::<u64>);
    bag.scan(summary.as_ref(), |m| {
        let k = by_channel.entry(m.channel.id).or_insert_with(|| key(&m.channel));
        let t = topics.entry(k.clone()).or_insert_with(|| new_topic(k));
        t.count += 1;
        t.first_log_time_ns = Some(t.first_log_time_ns.map_or(m.log_time, |v| v.min(m.log_time)));
        t.last_log_time_ns = Some(t.last_log_time_ns.map_or(m.log_time, |v| v.max(m.log_time)));
        count += 1;
        start = Some(start.map_or(m.log_time, |v| v.min(m.log_time)));
        end = Some(end.map_or(m.log_time, |v| v.max(m.log_time)));
        Ok(ControlFlow::Continue(()))
    })?;
    let (compression, chunk_count) = match &summary {
        Some(s) => {
            let set: BTreeSet<String> = s
                .chunk_indexes
                .iter()
                .map(|c| if c.compression.is_empty() { "none".to_string() } else { c.compression.clone() })
                .collect();
            (Some(set.into_iter().collect()), Some(s.chunk_indexes.len()))
        }
        None => (None, None),
    };
    Ok(BagInfo {
        path: bag.path,
        size_bytes: bag.len,
        profile,
        library,
        compression,
        chunk_count,
        message_count: count,
        start_log_time_ns: start,
        end_log_time_ns: end,
        topics: topics.into_values().collect(),
    })
}

impl fmt::Display for BagInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = self.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        writeln!(f, "Files:             {name}")?;
        writeln!(f, "Bag size:          {}", human_bytes(self.size_bytes))?;
        writeln!(f, "Storage id:        mcap (profile '{}', written by '{}')", self.profile, self.library)?;
        match (&self.compression, self.chunk_count) {
            (Some(c), Some(n)) if n > 0 => writeln!(f, "Compression:       {} ({n} chunks)", c.join(", "))?,
            (Some(_), _) => writeln!(f, "Compression:       none (no chunks)")?,
            _ => writeln!(f, "Compression:       unknown (no summary section)")?,
        }
        writeln!(f, "Duration:          {:.9}s", self.duration_s())?;
        let stamp = |t: Option<u64>| t.map_or("-".to_string(), fmt_ns);
        writeln!(f, "Start:             {} (log time, s since the epoch)", stamp(self.start_log_time_ns))?;
        writeln!(f, "End:               {}", stamp(self.end_log_time_ns))?;
        writeln!(f, "Messages:          {}", self.message_count)?;
        let w_topic = self.topics.iter().map(|t| t.topic.len()).max().unwrap_or(0);
        let w_type = self.topics.iter().map(|t| t.message_type.len()).max().unwrap_or(0);
        let w_count = self.topics.iter().map(|t| t.count.to_string().len()).max().unwrap_or(0);
        for (i, t) in self.topics.iter().enumerate() {
            let lead = if i == 0 { "Topic information: " } else { "                   " };
            let rate = t.rate_hz().map_or("-".to_string(), |r| format!("{r:.2} Hz"));
            let note = if t.supported_type.is_some() { "" } else { " (odocal cannot read this type)" };
            writeln!(
                f,
                "{lead}Topic: {:<w_topic$} | Type: {:<w_type$} | Count: {:>w_count$} | Rate: {rate:>9} | Serialization Format: {}{note}",
                crate::output::visible(&t.topic),
                crate::output::visible(&t.message_type),
                t.count,
                crate::output::visible(&t.message_encoding)
            )?;
        }
        if self.topics.is_empty() {
            writeln!(f, "Topic information: none")?;
        }
        Ok(())
    }
}

/// `954473` → `932.1 KiB`.
fn human_bytes(n: u64) -> String {
    let units = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = n as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < units.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{n} B")
    } else {
        format!("{v:.1} {}", units[u])
    }
}

/// Seconds as the `f64` nearest the exact decimal value of `ns` nanoseconds
/// (correctly rounded, as parsing `sec.nanosec` text is).
fn ns_to_s(ns: i128) -> f64 {
    let sign = if ns < 0 { "-" } else { "" };
    let a = ns.unsigned_abs();
    format!("{sign}{}.{:09}", a / 1_000_000_000, a % 1_000_000_000).parse().unwrap_or(f64::NAN)
}

fn bag_err(path: &Path, topic: &str, reason: String) -> Error {
    Error::Bag { path: path.to_path_buf(), topic: Some(topic.to_string()), reason }
}

fn schema_name(c: &mcap::Channel) -> String {
    c.schema.as_ref().map_or_else(|| "(no schema)".to_string(), |s| s.name.clone())
}

/// Sorted, de-duplicated (topic, type) pairs.
fn topic_list<'a>(chans: impl Iterator<Item = &'a mcap::Channel<'a>>) -> Vec<(String, String)> {
    chans.map(|c| (c.topic.clone(), schema_name(c))).collect::<BTreeSet<_>>().into_iter().collect()
}

/// The message type of a channel, checking the encoding.
fn channel_type(path: &Path, c: &mcap::Channel) -> Result<MessageType> {
    let name = schema_name(c);
    let ty = MessageType::from_ros_name(&name).ok_or_else(|| Error::BagMessageType {
        path: path.to_path_buf(),
        topic: c.topic.clone(),
        found: name.clone(),
        supported: MessageType::ALL.iter().map(|t| t.ros_name()).collect(),
    })?;
    if c.message_encoding != "cdr" {
        return Err(bag_err(
            path,
            &c.topic,
            format!("message encoding '{}' ({name}); odocal reads 'cdr' (ROS 2) messages only", c.message_encoding),
        ));
    }
    Ok(ty)
}

/// The columns asked for, resolved against the topic's type.
struct Plan {
    ty: MessageType,
    /// (name, column); empty for "all of a JointState", filled from the first message.
    cols: Vec<(String, Column)>,
    /// Everything was asked for (`columns` empty).
    all: bool,
}

impl Plan {
    fn new(path: &Path, topic: &str, ty: MessageType, names: &[&str]) -> Result<Plan> {
        let mut cols = Vec::new();
        let mut seen = BTreeSet::new();
        for name in names {
            if !seen.insert(*name) {
                continue;
            }
            let c = columns::resolve(ty, name).ok_or_else(|| Error::BagColumn {
                path: path.to_path_buf(),
                topic: topic.to_string(),
                message_type: ty.ros_name(),
                column: name.to_string(),
                valid: ty.columns().iter().map(|c| c.to_string()).collect(),
            })?;
            cols.push((name.to_string(), c));
        }
        if names.is_empty() && ty != MessageType::JointState {
            cols = ty.columns().iter().enumerate().map(|(i, c)| (c.to_string(), Column::Fixed(i))).collect();
        }
        Ok(Plan { ty, cols, all: names.is_empty() })
    }
}

/// Rows collected so far.
#[derive(Default)]
struct Collect {
    t_s: Vec<f64>,
    values: Vec<Vec<f64>>,
    /// Per column, the joint's index in the last message's name list.
    joint_idx: Vec<usize>,
    /// The previous message's header stamp (ns), in file order.
    last_stamp_ns: Option<i128>,
}

/// The largest step back of a topic's header stamps, from one message to the
/// next in file order, that is taken for messages arriving out of order (the
/// rows are sorted by time); a larger one is the publisher's clock stepping
/// back, which sorting would interleave with the earlier rows.
const MAX_STAMP_STEP_BACK_NS: i128 = 500_000_000;

impl Collect {
    fn push(&mut self, path: &Path, topic: &str, plan: &mut Plan, m: &mcap::Message, time: TimeSource) -> Result<()> {
        let index = self.t_s.len() as u64;
        let log_time = fmt_ns(m.log_time);
        let (stamp, decoded) = columns::decode(plan.ty, &m.data).map_err(|e| {
            bag_err(path, topic, format!("message {index} (log time {log_time} s) is not a {}: {e}", plan.ty))
        })?;
        if time == TimeSource::HeaderStamp {
            self.check_stamp(stamp, index, &log_time).map_err(|reason| bag_err(path, topic, reason))?;
        }
        if plan.all && index == 0 {
            if let Decoded::Joints(j) = &decoded {
                for field in [JointField::Position, JointField::Velocity] {
                    for n in &j.name {
                        let c = Column::Joint { field, joint: n.to_string() };
                        plan.cols.push((format!("{}.{n}", field.name()), c));
                    }
                }
            }
        }
        if self.values.len() != plan.cols.len() {
            self.values = vec![Vec::new(); plan.cols.len()];
            self.joint_idx = vec![0; plan.cols.len()];
        }
        for (k, (_, col)) in plan.cols.iter().enumerate() {
            let v = match (col, &decoded) {
                (Column::Fixed(i), Decoded::Fixed(v)) => v.get(*i).copied(),
                (Column::Joint { field, joint }, Decoded::Joints(j)) => {
                    let cached = self.joint_idx[k];
                    let i = if j.name.get(cached).is_some_and(|n| n == joint) {
                        cached
                    } else {
                        j.name.iter().position(|n| n == joint).ok_or_else(|| Error::BagJoint {
                            path: path.to_path_buf(),
                            topic: topic.to_string(),
                            joint: joint.clone(),
                            index,
                            log_time_ns: m.log_time,
                            present: j.name.iter().map(|n| n.to_string()).collect(),
                        })?
                    };
                    self.joint_idx[k] = i;
                    let arr = match field {
                        JointField::Position => &j.position,
                        JointField::Velocity => &j.velocity,
                    };
                    Some(*arr.get(i).ok_or_else(|| {
                        bag_err(
                            path,
                            topic,
                            format!(
                                "message {index} (log time {log_time} s) has {} {} values for {} joint names",
                                arr.len(),
                                field.name(),
                                j.name.len()
                            ),
                        )
                    })?)
                }
                _ => None,
            };
            // Plan and decoder are built from the same type, so `None` cannot happen.
            self.values[k].push(v.unwrap_or(f64::NAN));
        }
        self.t_s.push(match time {
            TimeSource::HeaderStamp => ns_to_s(stamp.total_ns()),
            TimeSource::LogTime => ns_to_s(i128::from(m.log_time)),
        });
        Ok(())
    }

    /// Refuses a header stamp whose `nanosec` is not below 10⁹ and one that
    /// steps back more than [`MAX_STAMP_STEP_BACK_NS`] from the previous
    /// message's.
    fn check_stamp(&mut self, stamp: msg::Time, index: u64, log_time: &str) -> std::result::Result<(), String> {
        const FIX: &str = "fix the publisher's stamps or read the log time (time = \"log\" in the manifest's stream)";
        if stamp.nanosec >= 1_000_000_000 {
            return Err(format!(
                "message {index} (log time {log_time} s) has header.stamp.nanosec = {}, not below 10^9 (sec = {}): \
                 not a valid ROS time; {FIX}",
                stamp.nanosec, stamp.sec
            ));
        }
        let ns = stamp.total_ns();
        if let Some(prev) = self.last_stamp_ns.filter(|&p| p - ns > MAX_STAMP_STEP_BACK_NS) {
            return Err(format!(
                "the header clock steps back {} s at message {index} (log time {log_time} s): its stamp {} s is \
                 before message {}'s {} s (more than {} s back is a clock step, not messages out of order); {FIX}",
                ns_to_s(prev - ns),
                ns_to_s(ns),
                index - 1,
                ns_to_s(prev),
                ns_to_s(MAX_STAMP_STEP_BACK_NS)
            ));
        }
        self.last_stamp_ns = Some(ns);
        Ok(())
    }

    /// Sorts the rows by time (stably) and names the columns.
    fn finish(self, plan: Plan, source: String) -> Table {
        let Collect { mut t_s, mut values, .. } = self;
        if !t_s.windows(2).all(|w| w[0] <= w[1]) {
            let mut order: Vec<usize> = (0..t_s.len()).collect();
            order.sort_by(|&a, &b| t_s[a].total_cmp(&t_s[b]));
            t_s = order.iter().map(|&i| t_s[i]).collect();
            for v in &mut values {
                *v = order.iter().map(|&i| v[i]).collect();
            }
        }
        let columns = plan.cols.into_iter().map(|(n, _)| n).zip(values).collect();
        Table { t_s, columns, source }
    }
}

/// An open MCAP file.
struct Bag {
    path: PathBuf,
    file: File,
    len: u64,
    /// The longest record the MCAP reader may read: no longer than the file
    /// or its largest chunk ([`records::check_lengths`]).
    record_limit: usize,
    /// The compressed chunks in file order, for their decoders.
    compressed: Vec<records::CompressedChunk>,
}

impl Bag {
    /// Opens `path` as an MCAP bag: a file, or a bag directory holding one
    /// `.mcap` file. Refuses sqlite3 bags, files without the MCAP magic and
    /// files cut before their end ([`truncated`]).
    fn open(path: &Path) -> Result<Bag> {
        let io = |e: std::io::Error| Error::Io { path: path.to_path_buf(), source: e };
        let file_path = if path.is_dir() { bag_in_dir(path)? } else { path.to_path_buf() };
        crate::output::limited::require_regular_file(&file_path, "an MCAP bag").map_err(io)?;
        let mut file = File::open(&file_path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        let mut head = [0u8; 16];
        let n = read_up_to(&mut file, &mut head).map_err(io)?;
        let head = &head[..n];
        if head.starts_with(SQLITE_MAGIC) || file_path.extension().is_some_and(|e| e == "db3") {
            return Err(Error::BagSqlite { path: path.to_path_buf() });
        }
        if !head.starts_with(mcap::MAGIC) {
            return Err(Error::Bag {
                path: file_path,
                topic: None,
                reason: "not an MCAP file (it does not start with the MCAP magic bytes)".into(),
            });
        }
        file.seek(std::io::SeekFrom::Start(mcap::MAGIC.len() as u64)).map_err(io)?;
        let checked = records::check_lengths(&mut file, mcap::MAGIC.len() as u64, len);
        // Every MCAP file ends with its footer record and the magic again:
        // without them, and with no damaged record before the end (a record
        // running past the end is where the cut fell), the file was cut.
        let mut tail = [0u8; 8];
        file.seek(std::io::SeekFrom::Start(len.saturating_sub(tail.len() as u64))).map_err(io)?;
        let n = read_up_to(&mut file, &mut tail).map_err(io)?;
        let ends_as_mcap = len >= FOOTER_AND_MAGICS && n == tail.len() && tail[..] == *mcap::MAGIC;
        let bag_error = |reason| Error::Bag { path: file_path.clone(), topic: None, reason };
        let checked = match checked {
            Ok(c) if ends_as_mcap => c,
            Ok(_) => return Err(bag_error(truncated(&file_path, len, None))),
            Err(records::LengthError::PastEnd(what)) if !ends_as_mcap => {
                return Err(bag_error(truncated(&file_path, len, Some(what))))
            }
            Err(e) => return Err(bag_error(e.to_string())),
        };
        Ok(Bag { path: file_path, file, len, record_limit: checked.record_limit, compressed: checked.compressed })
    }

    /// The summary section, when the file has a readable one. A missing or
    /// unreadable summary is not an error here: the linear scan that follows
    /// reports what is wrong with the file, at the place it goes wrong.
    fn summary(&mut self) -> Option<mcap::Summary> {
        use mcap::sans_io::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
        let opts = SummaryReaderOptions::default().with_file_size(self.len).with_record_length_limit(self.record_limit);
        let mut reader = SummaryReader::new_with_options(opts);
        // As in `scan`: a panic of the mcap reader on a damaged file means
        // no usable summary.
        loop {
            let Some(event) = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| reader.next_event())).ok()?
            else {
                break;
            };
            match event.ok()? {
                SummaryReadEvent::ReadRequest(n) => {
                    let read = self.file.read(reader.insert(n)).ok()?;
                    reader.notify_read(read);
                }
                SummaryReadEvent::SeekRequest(to) => {
                    let pos = self.file.seek(to).ok()?;
                    reader.notify_seeked(pos);
                }
            }
        }
        reader.finish()
    }

    /// The header record's profile and library (its string lengths were
    /// checked by the length walk at [`Bag::open`]).
    fn header(&mut self) -> Result<(String, String)> {
        let corrupt = |reason: String| Error::Bag { path: self.path.clone(), topic: None, reason };
        self.file.rewind().map_err(|e| Error::Io { path: self.path.clone(), source: e })?;
        let mut head = [0u8; 8 + 1 + 8];
        let n = read_up_to(&mut self.file, &mut head).map_err(|e| Error::Io { path: self.path.clone(), source: e })?;
        let mut len_bytes = [0u8; 8];
        len_bytes.copy_from_slice(&head[9..17]);
        let len = u64::from_le_bytes(len_bytes);
        if n < head.len() || head[8] != mcap::records::op::HEADER || len > 1 << 20 || len > self.len {
            return Err(corrupt("corrupt MCAP file: no valid header record after the magic".into()));
        }
        let mut body = vec![0u8; len as usize];
        self.file.read_exact(&mut body).map_err(|_| corrupt("truncated MCAP file: the header record is cut".into()))?;
        match mcap::parse_record(mcap::records::op::HEADER, &body) {
            Ok(mcap::records::Record::Header(h)) => Ok((h.profile, h.library)),
            Ok(_) | Err(_) => Err(corrupt("corrupt MCAP file: the header record does not parse".into())),
        }
    }

    /// Reads every message in file order, calling `f` on each until it
    /// returns `Break`, with the
    /// chunks' and the data section's CRCs verified. With the file's
    /// `summary`, a chunk whose index declares no uncompressed bytes is
    /// refused before reading, and the messages read must be as many as its
    /// statistics record declares (a chunk that declares fewer bytes than it
    /// holds is otherwise skipped silently).
    fn scan(
        &mut self,
        summary: Option<&mcap::Summary>,
        mut f: impl FnMut(&mcap::Message) -> Result<ControlFlow<()>>,
    ) -> Result<()> {
        let corrupt = |reason: String| Error::Bag { path: self.path.clone(), topic: None, reason };
        if let Some(c) =
            summary.and_then(|s| s.chunk_indexes.iter().find(|c| c.uncompressed_size == 0 && c.compressed_size > 0))
        {
            return Err(corrupt(format!(
                "corrupt MCAP file: the chunk at byte offset {} declares 0 uncompressed bytes for {} compressed ones",
                c.chunk_start_offset, c.compressed_size
            )));
        }
        self.file.rewind().map_err(|e| Error::Io { path: self.path.clone(), source: e })?;
        let opts = mcap::sans_io::LinearReaderOptions::default()
            .with_record_length_limit(self.record_limit)
            .with_validate_chunk_crcs(true)
            .with_validate_data_section_crc(true);
        let position = std::cell::Cell::new(0u64);
        let source = Counted { inner: BufReader::new(&mut self.file), read: &position };
        let mut reader = mcap::io::MessageReader::new_with_options(source, opts);
        for codec in decompress::Codec::ALL {
            reader
                .add_decompressor(decompress::ChunkDecoder::new(codec, &self.compressed))
                .map_err(|e| corrupt(format!("the {} decoder could not be set up: {e}", codec.name())))?;
        }
        let mut count = 0u64;
        loop {
            // mcap 0.26's linear reader can panic on a damaged file (an
            // unchecked `compressed_remaining -= len` in an uncompressed chunk
            // whose record claims more bytes than the chunk holds: an
            // overflow panic in debug builds, found by the damaged-bag
            // proptest). A damaged file must give an error, never a panic, so
            // the reader's step is isolated; our own callback `f` is not.
            let next = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| reader.next()))
                .map_err(|_| corrupt("corrupt MCAP file: a record's length does not fit its chunk".into()))?;
            let Some(m) = next else { break };
            let m = m.map_err(|e| corrupt(scan_error(&e, position.get(), summary)))?;
            count += 1;
            if f(&m)?.is_break() {
                return Ok(());
            }
        }
        match summary.and_then(|s| s.stats.as_ref()) {
            Some(st) if st.message_count != count => Err(corrupt(format!(
                "corrupt MCAP file: its statistics record declares {} messages, {count} were read (a chunk \
                 declares the wrong size or was cut)",
                st.message_count
            ))),
            _ => Ok(()),
        }
    }
}

/// The fewest bytes of a complete MCAP file: the magic, the footer record
/// (opcode, length and 20 bytes) and the magic again.
const FOOTER_AND_MAGICS: u64 = 8 + 1 + 8 + 20 + 8;

/// Why a file of `len` bytes that starts as MCAP but does not end as one
/// is refused, with where its records stop (`cut`: the record the length
/// walk found running past the end, if any), and what to do: the recording
/// was cut, and the mcap CLI's `recover` copies what it holds into a
/// complete file.
fn truncated(path: &Path, len: u64, cut: Option<String>) -> String {
    let stop = cut.map(|what| format!(" ({what})")).unwrap_or_default();
    format!(
        "truncated MCAP file: it ends after {len} bytes without the footer and closing magic bytes that end every \
         MCAP file{stop}. The recording was cut (a recorder stopped without closing the bag, or a copy or \
         download was interrupted): copy the messages it holds into a complete file with the mcap CLI, `mcap \
         recover {} -o recovered.mcap`, and give that file; or copy or record the drive again",
        path.display()
    )
}

/// The message of a reading error `e` found after `read` bytes of the file,
/// naming the chunk it is in ([`chunk_at`]).
fn scan_error(e: &mcap::McapError, read: u64, summary: Option<&mcap::Summary>) -> String {
    match e {
        mcap::McapError::Io(io) => format!("reading the MCAP file failed: {io}"),
        // The chunk decoders' own messages name the chunk (decompress.rs).
        mcap::McapError::DecompressionError(reason) if reason.starts_with("corrupt MCAP file") => reason.clone(),
        mcap::McapError::BadChunkCrc { saved, calculated } => format!(
            "corrupt MCAP file: {} fails its CRC check (stored {saved:#010x}, computed {calculated:#010x}): its \
             bytes are damaged",
            chunk_at(read, summary)
        ),
        mcap::McapError::BadDataCrc { saved, calculated } => format!(
            "corrupt MCAP file: the data section fails its CRC check (stored {saved:#010x}, computed \
             {calculated:#010x}): its bytes are damaged"
        ),
        mcap::McapError::Parse(_) => format!(
            "corrupt MCAP file: a record in {} does not parse (a string, map or field declares more bytes than \
             the record holds)",
            chunk_at(read, summary)
        ),
        mcap::McapError::RecordTooLarge { opcode, len } => format!(
            "corrupt MCAP file: a record (opcode {opcode:#04x}) in {} declares {len} bytes, more than the chunk or \
             file holding it",
            chunk_at(read, summary)
        ),
        e => format!("corrupt or truncated MCAP file: {e} (in {})", chunk_at(read, summary)),
    }
}

/// The chunk the reader was in after reading `read` bytes: the last one
/// starting before, from the summary's chunk indexes, else the offset.
fn chunk_at(read: u64, summary: Option<&mcap::Summary>) -> String {
    summary
        .and_then(|s| {
            let n = s.chunk_indexes.len();
            s.chunk_indexes.iter().enumerate().rev().find(|(_, c)| c.chunk_start_offset < read).map(|(i, c)| {
                format!("chunk {} of {n} (byte offset {}, {} bytes)", i + 1, c.chunk_start_offset, c.chunk_length)
            })
        })
        .unwrap_or_else(|| format!("the part of the file before byte offset {read}"))
}

/// A reader that counts the bytes it hands out, so an error of the MCAP
/// reader can say where in the file it happened.
struct Counted<'a, R> {
    /// The source.
    inner: R,
    /// Bytes read so far.
    read: &'a std::cell::Cell<u64>,
}

impl<R: Read> Read for Counted<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.read.set(self.read.get() + n as u64);
        Ok(n)
    }
}

/// Refuses stamps that are all the same (never set): the rows would have
/// no order and the stream no rate.
fn clock_steps(path: &Path, topic: &str, t_s: &[f64], time: TimeSource) -> Result<()> {
    let fix = match time {
        TimeSource::HeaderStamp => "use the log time (time = \"log\" in a manifest) or fix the recorder's stamps",
        TimeSource::LogTime => "the bag's log times are corrupt",
    };
    if t_s.len() > 1 && t_s.iter().all(|t| t.to_bits() == t_s[0].to_bits()) {
        let reason = format!(
            "all {} messages have the same time stamp ({} s): the stamps are not set; {fix}",
            t_s.len(),
            t_s[0]
        );
        return Err(bag_err(path, topic, reason));
    }
    Ok(())
}

/// Reads until `buf` is full or the file ends; returns the bytes read.
fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// The `.mcap` file of a bag directory (rosbag2 writes `metadata.yaml` and
/// one or more storage files).
fn bag_in_dir(dir: &Path) -> Result<PathBuf> {
    let entries = std::fs::read_dir(dir).map_err(|e| Error::Io { path: dir.to_path_buf(), source: e })?;
    let mut mcaps = Vec::new();
    let mut db3 = false;
    for e in entries {
        let p = e.map_err(|e| Error::Io { path: dir.to_path_buf(), source: e })?.path();
        match p.extension().and_then(|e| e.to_str()) {
            Some("mcap") => mcaps.push(p),
            Some("db3") => db3 = true,
            _ => {}
        }
    }
    mcaps.sort();
    match (mcaps.len(), db3) {
        (1, _) => Ok(mcaps.remove(0)),
        (0, true) => Err(Error::BagSqlite { path: dir.to_path_buf() }),
        (0, false) => Err(Error::Bag {
            path: dir.to_path_buf(),
            topic: None,
            reason: "a directory without an .mcap file; give the bag's .mcap file".into(),
        }),
        (n, _) => Err(Error::Bag {
            path: dir.to_path_buf(),
            topic: None,
            reason: format!(
                "a split bag of {n} .mcap files ({}); odocal reads one file at a time: give one of them",
                mcaps.iter().filter_map(|p| p.file_name()).map(|n| n.to_string_lossy()).collect::<Vec<_>>().join(", ")
            ),
        }),
    }
}
