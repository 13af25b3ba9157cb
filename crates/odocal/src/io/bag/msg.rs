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

/// `sensor_msgs/msg/JointState`.
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

/// Encodes a message as ROS 2 writes it (little-endian CDR with its
/// encapsulation header); for tests that write bags.
#[cfg(test)]
pub(crate) fn encode<T: Serialize>(msg: &T) -> Vec<u8> {
    let mut out = vec![0x00, 0x01, 0x00, 0x00];
    out.extend(cdr_encoding::to_vec::<T, byteorder::LittleEndian>(msg).expect("CDR encoding of a test message"));
    out
}
