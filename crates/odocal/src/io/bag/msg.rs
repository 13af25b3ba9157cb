//! Serde structs for the ROS 2 (Jazzy) messages odocal reads, and their
//! CDR decoding.
//!
//! Field order and types follow the `.msg` definitions exactly: CDR is not
//! self-describing, so the struct *is* the wire format. Fixed-size arrays
//! (`float64[9]`, `float64[36]`) have no length prefix; unbounded ones
//! (`string[]`, `float64[]`) have a `uint32` count. Alignment is relative to
//! the first byte after the 4-byte encapsulation header.

use serde::de::{self, SeqAccess, Visitor};
use serde::ser::SerializeTuple;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// Nanoseconds since the epoch (exact).
    pub(super) fn total_ns(self) -> i128 {
        i128::from(self.sec) * 1_000_000_000 + i128::from(self.nanosec)
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

/// `geometry_msgs/msg/Point` and `geometry_msgs/msg/Vector3` (same layout).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub(crate) struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Self { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
    }
}

impl Quaternion {
    /// Yaw (rotation about z, counter-clockwise, rad) of the ZYX Euler
    /// decomposition: `atan2(2(wz + xy), 1 − 2(y² + z²))`. For a yaw-only
    /// quaternion `(0, 0, sin(ψ/2), cos(ψ/2))` this is ψ wrapped to [−π, π].
    pub(super) fn yaw_rad(&self) -> f64 {
        let siny_cosp = 2.0 * (self.w * self.z + self.x * self.y);
        let cosy_cosp = 1.0 - 2.0 * (self.y * self.y + self.z * self.z);
        siny_cosp.atan2(cosy_cosp)
    }
}

/// `geometry_msgs/msg/Pose`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct Pose {
    pub position: Vector3,
    pub orientation: Quaternion,
}

/// `geometry_msgs/msg/Twist`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

/// A `float64[36]`: a 6×6 row-major covariance over (x, y, z, roll, pitch,
/// yaw). serde's array impls stop at 32 elements, hence the hand-written
/// tuple (de)serialisation (a CDR fixed array has no length prefix).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Cov6(pub [f64; 36]);

impl Default for Cov6 {
    fn default() -> Self {
        Self([0.0; 36])
    }
}

impl Serialize for Cov6 {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut t = s.serialize_tuple(36)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

impl<'de> Deserialize<'de> for Cov6 {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Cov6;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("36 float64 values")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Cov6, A::Error> {
                let mut out = [0.0; 36];
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = seq.next_element()?.ok_or_else(|| de::Error::invalid_length(i, &self))?;
                }
                Ok(Cov6(out))
            }
        }
        d.deserialize_tuple(36, V)
    }
}

/// `geometry_msgs/msg/PoseWithCovariance`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct PoseWithCovariance {
    pub pose: Pose,
    pub covariance: Cov6,
}

/// `geometry_msgs/msg/TwistWithCovariance`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct TwistWithCovariance {
    pub twist: Twist,
    pub covariance: Cov6,
}

/// `sensor_msgs/msg/JointState` (for writing test bags; reading goes
/// through [`decode_joints`]).
#[cfg(test)]
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct JointState {
    pub header: Header,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

/// `geometry_msgs/msg/PoseWithCovarianceStamped`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct PoseWithCovarianceStamped {
    pub header: Header,
    pub pose: PoseWithCovariance,
}

/// `geometry_msgs/msg/PoseStamped`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

/// `nav_msgs/msg/Odometry`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

/// `sensor_msgs/msg/NavSatStatus`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct NavSatStatus {
    pub status: i8,
    pub service: u16,
}

/// `sensor_msgs/msg/NavSatFix`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct NavSatFix {
    pub header: Header,
    pub status: NavSatStatus,
    pub latitude: f64,
    pub longitude: f64,
    pub altitude: f64,
    pub position_covariance: [f64; 9],
    pub position_covariance_type: u8,
}

/// `sensor_msgs/msg/Imu`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub(crate) struct Imu {
    pub header: Header,
    pub orientation: Quaternion,
    pub orientation_covariance: [f64; 9],
    pub angular_velocity: Vector3,
    pub angular_velocity_covariance: [f64; 9],
    pub linear_acceleration: Vector3,
    pub linear_acceleration_covariance: [f64; 9],
}

/// The CDR encapsulation kinds ROS 2 writes: plain CDR, big or little endian
/// (`0x0000` / `0x0001`), the header's options bytes ignored.
const CDR_BE: [u8; 2] = [0x00, 0x00];
const CDR_LE: [u8; 2] = [0x00, 0x01];

/// Decodes one serialized ROS 2 message: a 4-byte encapsulation header, then
/// the CDR body. Trailing bytes (alignment padding some writers add) are
/// ignored. Never panics: truncated or garbled input is an `Err` naming what
/// went wrong.
pub(crate) fn decode<T: de::DeserializeOwned>(data: &[u8]) -> Result<T, String> {
    let (head, body) = data
        .split_at_checked(4)
        .ok_or_else(|| format!("{} bytes, shorter than the 4-byte CDR encapsulation header", data.len()))?;
    let kind = [head[0], head[1]];
    let r = if kind == CDR_LE {
        cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body)
    } else if kind == CDR_BE {
        cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body)
    } else {
        return Err(format!(
            "encapsulation {:#04x}{:02x} is not plain CDR (0x0000 big endian or 0x0001 little endian)",
            kind[0], kind[1]
        ));
    };
    r.map(|(v, _)| v).map_err(|e| format!("not valid CDR: {e}"))
}

/// The most joints odocal reads from one `JointState` message. Real robots
/// publish tens; the ceiling keeps a hostile message from making every row
/// of a topic hold hundreds of thousands of columns.
pub(crate) const MAX_JOINTS: usize = 65_536;

/// A decoded `sensor_msgs/msg/JointState`, its joint names borrowed from the
/// message bytes; `effort` is checked but not kept (odocal does not read it).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Joints<'a> {
    pub stamp: Time,
    pub name: Vec<&'a str>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
}

/// A CDR reader over one message body that checks every declared length
/// against the bytes left before allocating anything for it.
struct Cdr<'a> {
    body: &'a [u8],
    at: usize,
    big_endian: bool,
}

impl<'a> Cdr<'a> {
    fn left(&self) -> usize {
        self.body.len() - self.at
    }

    /// The next `n` bytes, after aligning to `align` (relative to the body's start).
    /// Nothing is taken (and no padding skipped) for `n` = 0, as a CDR
    /// reader reads no element of an empty sequence.
    fn take(&mut self, align: usize, n: usize, what: &str) -> Result<&'a [u8], String> {
        if n == 0 {
            return Ok(&[]);
        }
        let start = self.at.next_multiple_of(align);
        let end = start.checked_add(n).filter(|&e| e <= self.body.len()).ok_or_else(|| {
            format!("the message ends inside {what} ({n} bytes needed, {} left)", self.body.len().saturating_sub(start))
        })?;
        self.at = end;
        Ok(&self.body[start..end])
    }

    fn u32(&mut self, what: &str) -> Result<u32, String> {
        let b: [u8; 4] = self.take(4, 4, what)?.try_into().map_err(|_| format!("{what}: 4 bytes expected"))?;
        Ok(if self.big_endian { u32::from_be_bytes(b) } else { u32::from_le_bytes(b) })
    }

    fn f64(&mut self, what: &str) -> Result<f64, String> {
        let b: [u8; 8] = self.take(8, 8, what)?.try_into().map_err(|_| format!("{what}: 8 bytes expected"))?;
        Ok(if self.big_endian { f64::from_be_bytes(b) } else { f64::from_le_bytes(b) })
    }

    /// A CDR string: a `uint32` length that counts the terminating NUL, then the bytes.
    fn string(&mut self, what: &str) -> Result<&'a str, String> {
        let n = self.u32(what)? as usize;
        if n > self.left() {
            return Err(format!("{what} declares {n} bytes, more than the {} left in the message", self.left()));
        }
        let bytes = self.take(1, n, what)?;
        // The length counts the terminating NUL: the last byte is dropped
        // whatever it is, as ROS 2's CDR readers do.
        let text = bytes.split_last().map_or(bytes, |(_, text)| text);
        std::str::from_utf8(text).map_err(|e| format!("{what} is not UTF-8: {e}"))
    }

    /// The element count of a sequence whose elements take at least
    /// `min_bytes` each, checked against the bytes left and `MAX_JOINTS`.
    fn count(&mut self, what: &str, min_bytes: usize) -> Result<usize, String> {
        let n = self.u32(what)? as usize;
        let room = self.left() / min_bytes;
        if n > room {
            return Err(format!(
                "its {what} array declares {n} elements, more than the {} bytes left in the message hold",
                self.left()
            ));
        }
        if n > MAX_JOINTS {
            return Err(format!(
                "its {what} array has {n} elements; odocal reads at most {MAX_JOINTS} joints per message"
            ));
        }
        Ok(n)
    }

    fn f64_seq(&mut self, what: &str) -> Result<Vec<f64>, String> {
        let n = self.count(what, 8)?;
        let mut v = Vec::with_capacity(n);
        for _ in 0..n {
            v.push(self.f64(what)?);
        }
        Ok(v)
    }
}

/// Decodes a `sensor_msgs/msg/JointState` (4-byte encapsulation header, then
/// CDR) without trusting its lengths: every string and array length is
/// checked against the bytes left in the message before anything is
/// allocated for it, and a message may name at most [`MAX_JOINTS`] joints.
/// Reads the same values as the serde decoding ([`decode`]) of the
/// test-only `JointState` struct, which the bag tests hold it to.
pub(crate) fn decode_joints(data: &[u8]) -> Result<Joints<'_>, String> {
    let (head, body) = data
        .split_at_checked(4)
        .ok_or_else(|| format!("{} bytes, shorter than the 4-byte CDR encapsulation header", data.len()))?;
    let big_endian = match [head[0], head[1]] {
        CDR_LE => false,
        CDR_BE => true,
        kind => {
            return Err(format!(
                "encapsulation {:#04x}{:02x} is not plain CDR (0x0000 big endian or 0x0001 little endian)",
                kind[0], kind[1]
            ))
        }
    };
    let mut c = Cdr { body, at: 0, big_endian };
    let sec = c.u32("header.stamp.sec")? as i32;
    let nanosec = c.u32("header.stamp.nanosec")?;
    c.string("header.frame_id")?;
    let n = c.count("name", 4)?;
    let mut name = Vec::with_capacity(n);
    for _ in 0..n {
        name.push(c.string("a joint name")?);
    }
    let position = c.f64_seq("position")?;
    let velocity = c.f64_seq("velocity")?;
    let effort = c.count("effort", 8)?;
    c.take(8, effort * 8, "effort")?;
    Ok(Joints { stamp: Time { sec, nanosec }, name, position, velocity })
}

/// Encodes a message as ROS 2 writes it (little-endian CDR with its
/// encapsulation header); for tests that write bags.
#[cfg(test)]
pub(crate) fn encode<T: Serialize>(msg: &T) -> Vec<u8> {
    let mut out = vec![0x00, 0x01, 0x00, 0x00];
    out.extend(cdr_encoding::to_vec::<T, byteorder::LittleEndian>(msg).expect("CDR encoding of a test message"));
    out
}
