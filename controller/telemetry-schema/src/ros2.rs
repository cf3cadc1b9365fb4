//! ROS 2 messages as ROS 2 puts them on the wire and in MCAP files: CDR (XCDR1, little-endian,
//! the `cdr` message encoding) with the `ros2msg` definitions as schema. robodeploy writes the
//! ones viewers and ROS tools read by convention: the robot's description (`std_msgs/msg/String`
//! on `/robot_description`, a URDF) and its joints (`sensor_msgs/msg/JointState` on
//! `/joint_states`, each joint by name).
//! The messages' CDR is `dds::ros2`'s; here are their `ros2msg` definitions.

/// `std_msgs/msg/String`'s definition (schema name `std_msgs/msg/String`).
pub const STRING_DEFINITION: &str = "string data\n";

/// `sensor_msgs/msg/JointState`'s definition with the types it uses, as `ros2msg` schemas carry
/// them (schema name `sensor_msgs/msg/JointState`).
pub const JOINT_STATE_DEFINITION: &str = "\
std_msgs/Header header
string[] name
float64[] position
float64[] velocity
float64[] effort
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
";

pub use dds::ros2::{encode_joint_state, encode_string};
