//! ROS 2 messages as ROS 2 puts them on the wire and in MCAP files: CDR (XCDR1, little-endian,
//! the `cdr` message encoding) with the `ros2msg` definitions as schema. robodeploy writes the
//! ones viewers and ROS tools read by convention: the robot's description (`std_msgs/msg/String`
//! on `/robot_description`, a URDF) and its joints (`sensor_msgs/msg/JointState` on
//! `/joint_states`, each joint by name).
//! The encoding itself is `dds::cdr`'s.

use dds::cdr::CdrWriter;

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

/// `std_msgs/msg/String` `{ data: text }` into `buf`.
pub fn encode_string(buf: &mut Vec<u8>, text: &str) {
    CdrWriter::new(buf).string(text);
}

/// One `sensor_msgs/msg/JointState`: stamp, frame, and per joint its name, position (rad),
/// velocity (rad/s) and effort (N·m), into `buf`.
pub fn encode_joint_state<'n>(
    buf: &mut Vec<u8>,
    stamp_ns: u64,
    frame_id: &str,
    names: impl ExactSizeIterator<Item = &'n str>,
    position: impl ExactSizeIterator<Item = f64>,
    velocity: impl ExactSizeIterator<Item = f64>,
    effort: impl ExactSizeIterator<Item = f64>,
) {
    let mut c = CdrWriter::new(buf);
    c.time(stamp_ns).string(frame_id).count(names.len());
    for n in names {
        c.string(n);
    }
    c.f64s(position).f64s(velocity).f64s(effort);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_joint_state_aligns_its_doubles_to_eight_from_the_header() {
        let mut buf = Vec::new();
        encode_joint_state(
            &mut buf,
            1_500_000_000,
            "",
            ["knee"].into_iter(),
            [0.5].into_iter(),
            [-1.0].into_iter(),
            std::iter::empty(),
        );
        let body = &buf[4..];
        // stamp: sec 1, nanosec 5e8; frame_id "" (length 1, a NUL).
        assert_eq!(&body[..8], [1, 0, 0, 0, 0x00, 0x65, 0xcd, 0x1d]);
        assert_eq!(&body[8..13], [1, 0, 0, 0, 0]);
        // name: count 1 at 16 (after padding 13 → 16), "knee\0" (length 5) at 20..29.
        assert_eq!(&body[16..20], [1, 0, 0, 0]);
        assert_eq!(&body[20..24], [5, 0, 0, 0]);
        assert_eq!(&body[24..29], b"knee\0");
        // position: count at 32, the double at 40 (aligned to 8).
        assert_eq!(&body[32..36], [1, 0, 0, 0]);
        assert_eq!(&body[40..48], 0.5f64.to_le_bytes());
        // velocity: count at 48, its double at 56; effort: count 0 at 64.
        assert_eq!(&body[48..52], [1, 0, 0, 0]);
        assert_eq!(&body[56..64], (-1.0f64).to_le_bytes());
        assert_eq!(&body[64..], [0, 0, 0, 0]);
    }
}
