//! ROS 2 bag topics (`format = "mcap"`): one topic of an MCAP bag read with
//! [`crate::io::bag::read_topic`], its columns named as that module names them
//! (`position.<joint>`, `x`, `y`, `yaw`, `cov_x`, `latitude`, `status`,
//! `acc_y`, …), its time the header stamp or the log time.
//!
//! Errors of the bag reader keep their text (it names the topic and lists
//! what the bag has) behind the manifest key that asked: the column's key for
//! a missing column or joint, `streams.<name>.topic` for an unknown topic or
//! message type, `streams.<name>.file` for the file itself.

use std::path::Path;

use super::{Table, Wanted};
use crate::error::{Error, Result};
use crate::io::bag::{self, TimeSource};
use crate::io::import::manifest::{BagTime, Manifest};

/// Reads the `wanted` columns of `topic` in the bag at `path`.
pub(super) fn read(
    m: &Manifest,
    name: &str,
    path: &Path,
    topic: &str,
    time: BagTime,
    wanted: &[Wanted],
) -> Result<Table> {
    let time = match time {
        BagTime::Header => TimeSource::HeaderStamp,
        BagTime::Log => TimeSource::LogTime,
    };
    let mut columns: Vec<&str> = wanted.iter().map(|w| w.column.as_str()).collect();
    columns.sort_unstable();
    columns.dedup();
    let table = bag::read_topic(path, topic, &columns, time).map_err(|e| {
        let key = match &e {
            Error::BagColumn { column, .. } => key_of(wanted, |c| c == column),
            Error::BagJoint { joint, .. } => key_of(wanted, |c| c.split_once('.').is_some_and(|(_, j)| j == joint)),
            Error::BagTopicNotFound { .. } | Error::BagMessageType { .. } => None,
            _ => Some(format!("streams.{name}.file")),
        };
        m.error(&key.unwrap_or_else(|| format!("streams.{name}.topic")), e)
    })?;
    Ok(Table { t_s: table.t_s, columns: table.columns, source: table.source, lines: None, warnings: Vec::new() })
}

/// The manifest key of the first wanted column `is` matches.
fn key_of(wanted: &[Wanted], is: impl Fn(&str) -> bool) -> Option<String> {
    wanted.iter().find(|w| is(&w.column)).map(|w| w.key.clone())
}
