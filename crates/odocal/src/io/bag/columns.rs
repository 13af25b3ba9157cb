//! The message types odocal reads and the numeric columns each one yields.

use super::msg;

/// A ROS 2 message type odocal can turn into columns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub(crate) enum MessageType {
    /// `sensor_msgs/msg/JointState`: `position.<joint>` (rad or m),
    /// `velocity.<joint>` (rad/s or m/s).
    JointState,
    /// `geometry_msgs/msg/PoseWithCovarianceStamped`: `x`, `y`, `z` (m),
    /// `yaw` (rad), `cov_x`, `cov_y` (m²), `cov_yaw` (rad²).
    PoseWithCovarianceStamped,
    /// `geometry_msgs/msg/PoseStamped`: `x`, `y`, `z` (m), `yaw` (rad).
    PoseStamped,
    /// `nav_msgs/msg/Odometry`: the pose columns of
    /// `PoseWithCovarianceStamped` plus `v_x` (m/s, twist linear x) and
    /// `omega_z` (rad/s, twist angular z), both in the child frame.
    Odometry,
    /// `sensor_msgs/msg/NavSatFix`: `latitude`, `longitude` (deg),
    /// `altitude` (m), `status` (`status.status`: −1 no fix … 2 GBAS),
    /// `cov_e`, `cov_n`, `cov_u` (m², the diagonal of `position_covariance`).
    NavSatFix,
    /// `sensor_msgs/msg/Imu`: `acc_x`, `acc_y`, `acc_z` (m/s²),
    /// `gyro_x`, `gyro_y`, `gyro_z` (rad/s), in the IMU frame.
    Imu,
}

const POSE_COLS: &[&str] = &["x", "y", "z", "yaw", "cov_x", "cov_y", "cov_yaw"];
const POSE_STAMPED_COLS: &[&str] = &["x", "y", "z", "yaw"];
const ODOM_COLS: &[&str] = &["x", "y", "z", "yaw", "cov_x", "cov_y", "cov_yaw", "v_x", "omega_z"];
const FIX_COLS: &[&str] = &["latitude", "longitude", "altitude", "status", "cov_e", "cov_n", "cov_u"];
const IMU_COLS: &[&str] = &["acc_x", "acc_y", "acc_z", "gyro_x", "gyro_y", "gyro_z"];
const JOINT_COLS: &[&str] = &["position.<joint name>", "velocity.<joint name>"];

impl MessageType {
    /// Every supported type.
    pub(crate) const ALL: [MessageType; 6] = [
        MessageType::JointState,
        MessageType::PoseWithCovarianceStamped,
        MessageType::PoseStamped,
        MessageType::Odometry,
        MessageType::NavSatFix,
        MessageType::Imu,
    ];

    /// The type from its ROS 2 name (`sensor_msgs/msg/JointState`), as MCAP
    /// schema records name it; `None` for a type odocal does not read.
    pub(crate) fn from_ros_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.ros_name() == name)
    }

    /// The ROS 2 type name, e.g. `sensor_msgs/msg/JointState`.
    pub(crate) fn ros_name(self) -> &'static str {
        match self {
            MessageType::JointState => "sensor_msgs/msg/JointState",
            MessageType::PoseWithCovarianceStamped => "geometry_msgs/msg/PoseWithCovarianceStamped",
            MessageType::PoseStamped => "geometry_msgs/msg/PoseStamped",
            MessageType::Odometry => "nav_msgs/msg/Odometry",
            MessageType::NavSatFix => "sensor_msgs/msg/NavSatFix",
            MessageType::Imu => "sensor_msgs/msg/Imu",
        }
    }

    /// The column names this type yields. For `JointState` they are the
    /// patterns `position.<joint name>` and `velocity.<joint name>`.
    pub(crate) fn columns(self) -> &'static [&'static str] {
        match self {
            MessageType::JointState => JOINT_COLS,
            MessageType::PoseWithCovarianceStamped => POSE_COLS,
            MessageType::PoseStamped => POSE_STAMPED_COLS,
            MessageType::Odometry => ODOM_COLS,
            MessageType::NavSatFix => FIX_COLS,
            MessageType::Imu => IMU_COLS,
        }
    }
}

impl std::fmt::Display for MessageType {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.ros_name())
    }
}

/// Which of a joint's arrays a `JointState` column takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum JointField {
    Position,
    Velocity,
}

impl JointField {
    pub(super) fn name(self) -> &'static str {
        match self {
            JointField::Position => "position",
            JointField::Velocity => "velocity",
        }
    }
}

/// One requested column, resolved against the message type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Column {
    /// A fixed field, by its index in the type's column list.
    Fixed(usize),
    /// A joint's position or velocity.
    Joint { field: JointField, joint: String },
}

/// Resolves a column name for `ty`; `None` when the type has no such column.
pub(crate) fn resolve(ty: MessageType, name: &str) -> Option<Column> {
    if ty == MessageType::JointState {
        let (field, joint) = name.split_once('.')?;
        let field = match field {
            "position" => JointField::Position,
            "velocity" => JointField::Velocity,
            _ => return None,
        };
        return (!joint.is_empty()).then(|| Column::Joint { field, joint: joint.to_string() });
    }
    ty.columns().iter().position(|c| *c == name).map(Column::Fixed)
}

/// A decoded message, reduced to what the columns need.
pub(crate) enum Decoded<'a> {
    /// Joint names and their arrays.
    Joints(msg::Joints<'a>),
    /// Values in the order of the type's column list.
    Fixed(Vec<f64>),
}

/// Decodes a message of type `ty`; returns its header stamp and contents.
pub(crate) fn decode(ty: MessageType, data: &[u8]) -> Result<(msg::Time, Decoded<'_>), String> {
    fn pose_values(p: &msg::PoseWithCovariance) -> [f64; 7] {
        let c = &p.covariance.0;
        let q = &p.pose.orientation;
        [p.pose.position.x, p.pose.position.y, p.pose.position.z, q.yaw_rad(), c[0], c[7], c[35]]
    }
    Ok(match ty {
        MessageType::JointState => {
            let m = msg::decode_joints(data)?;
            (m.stamp, Decoded::Joints(m))
        }
        MessageType::PoseWithCovarianceStamped => {
            let m: msg::PoseWithCovarianceStamped = msg::decode(data)?;
            (m.header.stamp, Decoded::Fixed(pose_values(&m.pose).to_vec()))
        }
        MessageType::PoseStamped => {
            let m: msg::PoseStamped = msg::decode(data)?;
            let p = &m.pose.position;
            (m.header.stamp, Decoded::Fixed(vec![p.x, p.y, p.z, m.pose.orientation.yaw_rad()]))
        }
        MessageType::Odometry => {
            let m: msg::Odometry = msg::decode(data)?;
            let mut v = pose_values(&m.pose).to_vec();
            v.extend([m.twist.twist.linear.x, m.twist.twist.angular.z]);
            (m.header.stamp, Decoded::Fixed(v))
        }
        MessageType::NavSatFix => {
            let m: msg::NavSatFix = msg::decode(data)?;
            let c = &m.position_covariance;
            let v = vec![m.latitude, m.longitude, m.altitude, f64::from(m.status.status), c[0], c[4], c[8]];
            (m.header.stamp, Decoded::Fixed(v))
        }
        MessageType::Imu => {
            let m: msg::Imu = msg::decode(data)?;
            let (a, w) = (&m.linear_acceleration, &m.angular_velocity);
            (m.header.stamp, Decoded::Fixed(vec![a.x, a.y, a.z, w.x, w.y, w.z]))
        }
    })
}
