//! A draft drive manifest for a bag ([`BagInfo::draft_manifest`], `odocal inspect BAG
//! --manifest`): the topics odocal reads, chosen by message type, written as
//! a manifest that imports as it stands, with every guess marked `CHECK` in
//! a comment for the user to confirm.
//!
//! The choices, in order of preference:
//! - **wheels**: the `JointState` topic with the most messages; the joints
//!   whose names say rear (or back) and left / right (any left / right
//!   joint otherwise, the first two joints as a last resort); positions
//!   (`rad_cumulative`) where the messages carry them, else velocities
//!   (`rad_per_s`). One model revolution is then one wheel revolution, so
//!   `c_e` is the physical circumference.
//! - **pose**: `PoseWithCovarianceStamped`, `Odometry`, `PoseStamped` (local
//!   x, y and yaw, ENU) or else `NavSatFix` (latitude/longitude; the heading
//!   derived from the track).
//! - **lateral acceleration**: an `Imu` topic's `acc_y` (REP-103 body axes:
//!   y to the left), else derived from the wheels; sideslip zero.

use std::fmt::Write as _;

use super::{first_message, BagInfo, MessageType, TopicInfo};
use crate::error::{Error, Result};

/// A TOML basic string (quoted and escaped).
fn quoted(s: &str) -> String {
    toml::Value::String(s.to_string()).to_string()
}

/// The readable topic of the first of `types` the bag has, the one with the
/// most messages among those of that type.
fn pick<'a>(topics: &'a [TopicInfo], types: &[MessageType]) -> Option<(&'a TopicInfo, MessageType)> {
    types.iter().find_map(|ty| {
        topics.iter().filter(|t| t.supported_type == Some(*ty) && t.count > 0).max_by_key(|t| t.count).map(|t| (t, *ty))
    })
}

/// The joint of `names` for one rear wheel (`side` "left" or "right"), and
/// whether it is a guess: a name with rear/back and the side, else the side
/// alone, else `fallback`.
fn joint<'a>(names: &[&'a str], side: &str, fallback: usize) -> (Option<&'a str>, bool) {
    let has = |n: &str, w: &str| n.to_ascii_lowercase().contains(w);
    let rear = |n: &str| has(n, "rear") || has(n, "back");
    if let Some(n) = names.iter().find(|n| rear(n) && has(n, side)) {
        return (Some(*n), false);
    }
    if let Some(n) = names.iter().find(|n| has(n, side)) {
        return (Some(*n), true);
    }
    (names.get(fallback).copied(), true)
}

impl BagInfo {
    /// A draft manifest (TOML text) that imports the drive in this bag: the
    /// wheel, pose and IMU topics chosen by message type (see the module docs),
    /// every guess marked `CHECK`. `file` is the bag's path as the manifest
    /// should name it (relative to where the manifest will be, or absolute).
    ///
    /// # Errors
    /// What [`read_topic`](super::read_topic) returns reading the wheel topic's
    /// first message; [`Error::Bag`] when the bag has no wheel (`JointState`)
    /// or no pose topic odocal reads.
    pub fn draft_manifest(&self, file: &str) -> Result<String> {
        let (info, bag) = (self, self.path.as_path());
        let missing = |what: &str| {
            Error::Bag {
            path: bag.to_path_buf(),
            topic: None,
            reason: format!(
                "no {what} topic odocal reads (it reads {}); write the manifest by hand (docs/reference.md, \"The drive manifest\")",
                MessageType::ALL.iter().map(|t| t.ros_name()).collect::<Vec<_>>().join(", ")
            ),
        }
        };
        let (wheels, _) =
            pick(&info.topics, &[MessageType::JointState]).ok_or_else(|| missing("wheel (JointState)"))?;
        let pose_types = [
            MessageType::PoseWithCovarianceStamped,
            MessageType::Odometry,
            MessageType::PoseStamped,
            MessageType::NavSatFix,
        ];
        let (pose, pose_type) = pick(&info.topics, &pose_types).ok_or_else(|| missing("pose"))?;
        let imu = pick(&info.topics, &[MessageType::Imu]).map(|(t, _)| t);

        // The joints the first message names, and which fields they carry.
        let table = first_message(bag, &wheels.topic)?;
        let (positions, velocities) = (table.joints("position"), table.joints("velocity"));
        let (field, signal, names) = if positions.len() >= 2 {
            ("position", "rad_cumulative", positions)
        } else {
            ("velocity", "rad_per_s", velocities)
        };
        let (left, left_guess) = joint(&names, "left", 0);
        let (right, right_guess) = joint(&names, "right", 1);
        let (Some(left), Some(right)) = (left, right) else {
            return Err(Error::Bag {
                path: bag.to_path_buf(),
                topic: Some(wheels.topic.clone()),
                reason: format!("fewer than two joints with {field}s ({}): no rear wheel pair", names.join(", ")),
            });
        };

        let mut m = String::new();
        let w = &mut m;
        let _ = writeln!(w, "# Draft manifest for {}, written by `odocal inspect --manifest`.", quoted(file));
        let _ = writeln!(w, "# The topics were chosen by message type: confirm every line marked CHECK, then");
        let _ = writeln!(w, "#   odocal import THIS.toml --out drive.csv     (or give THIS.toml to calibrate).");
        let _ =
            writeln!(w, "# The format: docs/reference.md, \"The drive manifest\". Paths are relative to this file.");
        let _ = writeln!(w, "\n[output]\nrate_hz = 40.0\nmax_gap_s = 0.5\nclock_offset = \"auto\"");
        let _ = writeln!(w, "theta0 = [2.0, 0.0, 1.6, 0.0]   # c_e per wheel revolution (2 pi rad of joint angle)");

        // One `[streams.NAME]` table per topic, saying what the topic is.
        let stream = |w: &mut String, name: &str, t: &TopicInfo| {
            let rate = t.rate_hz().map(|r| format!("{r:.1} Hz")).unwrap_or_else(|| "rate unknown".into());
            let _ = writeln!(w, "\n[streams.{name}]\nformat = \"mcap\"\nfile = {}", quoted(file));
            let ty = crate::output::visible(&t.message_type);
            let _ = writeln!(w, "topic = {}   # {ty}, {} messages, {rate}", quoted(&t.topic), t.count);
        };
        stream(w, "wheels", wheels);
        let _ =
            writeln!(w, "time = \"header\"   # CHECK: \"log\" if the header stamps are not on the other topics' clock");
        if let Some(r) = wheels.rate_hz() {
            let _ = writeln!(
                w,
                "# nominal_rate_hz = {:.0}   # CHECK: set it when the stamps jitter (stamped on arrival)",
                r.round()
            );
        }
        stream(w, "pose", pose);
        if let Some(t) = imu {
            stream(w, "imu", t);
        }

        let mark = |guess: bool| if guess { "   # CHECK: a guess from the joint names" } else { "" };
        let _ = writeln!(w, "\n[wheels]\nstream = \"wheels\"");
        let _ = writeln!(
            w,
            "signal = \"{signal}\"   # joint {field}s; CHECK: sign = -1 on a wheel whose {field} falls driving forward"
        );
        let _ = writeln!(w, "rear_left = {{ column = {} }}{}", quoted(&format!("{field}.{left}")), mark(left_guess));
        let _ = writeln!(w, "rear_right = {{ column = {} }}{}", quoted(&format!("{field}.{right}")), mark(right_guess));
        if left_guess || right_guess {
            let _ = writeln!(
                w,
                "# the joints of {}: {}",
                crate::output::visible(&wheels.topic),
                crate::output::visible(&names.join(", "))
            );
        }

        write_pose_tables(w, pose_type);
        write_lateral_acceleration(w, imu.is_some());
        let _ = writeln!(w, "\n[sideslip]\nsource = \"zero\"");
        Ok(m)
    }
}

/// The draft's `[pose]` tables for a pose topic of this message type.
fn write_pose_tables(w: &mut String, pose_type: MessageType) {
    let _ = writeln!(w, "\n[pose]\nstream = \"pose\"");
    if pose_type == MessageType::NavSatFix {
        let _ = writeln!(
            w,
            "\n[pose.position]\nkind = \"lat_lon\"\nlat = \"latitude\"\nlon = \"longitude\"\nalt = \"altitude\""
        );
        let _ = writeln!(
            w,
            "# no [pose.heading]: derived from the track (NavSatFix has none), over a chord of\n\
             # pose.derive_heading_baseline_m (default 2 m) of travel; see the manifest reference"
        );
        let _ = writeln!(w, "\n# [pose.quality]   # CHECK: keep only good fixes, e.g. status 2 (GBAS/RTK)");
        let _ = writeln!(w, "# column = \"status\"\n# accept = [2]");
    } else {
        let _ = writeln!(w, "\n[pose.position]\nkind = \"local\"   # CHECK: the frame is local metres (e.g. map, ENU)");
        let _ = writeln!(w, "x = \"x\"\ny = \"y\"");
        let _ = writeln!(w, "\n[pose.heading]\ncolumn = \"yaw\"   # from the quaternion, counter-clockwise from x\nconvention = \"enu\"\nunit = \"rad\"");
        if pose_type != MessageType::PoseStamped {
            // A calibration needs a good reference: poses whose covariance
            // says σ > 0.1 m split the drive (on the van's log the RTK-float
            // stretches jump by metres).
            let _ = writeln!(
                w,
                "\n[pose.quality]   # CHECK: poses with a larger x variance (m², σ > 0.1 m) split the drive"
            );
            let _ = writeln!(w, "column = \"cov_x\"\nmax = 0.01");
        }
    }
}

/// The draft's `[lateral_acceleration]` table: the IMU's when the bag has one.
fn write_lateral_acceleration(w: &mut String, has_imu: bool) {
    if has_imu {
        let _ = writeln!(w, "\n[lateral_acceleration]\nsource = \"imu\"\nstream = \"imu\"\ncolumn = \"acc_y\"");
        let _ = writeln!(w, "sign = 1   # CHECK: REP-103 body axes (y left); -1 if the IMU's y points right");
    } else {
        let _ = writeln!(w, "\n[lateral_acceleration]\nsource = \"from_wheels\"   # no Imu topic in the bag");
    }
}
