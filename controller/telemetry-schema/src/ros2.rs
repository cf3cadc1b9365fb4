//! ROS 2 messages as ROS 2 puts them on the wire and in MCAP files: CDR (XCDR1, little-endian,
//! the `cdr` message encoding) with the `ros2msg` definitions as schema. robodeploy writes the
//! ones viewers and ROS tools read by convention: the robot's description (`std_msgs/msg/String`
//! on `/robot_description`, a URDF) and its joints (`sensor_msgs/msg/JointState` on
//! `/joint_states`, each joint by name).
//!
//! CDR aligns each primitive to its own size, counted from the end of the 4-byte encapsulation
//! header; strings are a `uint32` length including the terminating NUL, then the bytes and the
//! NUL; sequences are a `uint32` count, then the elements.

/// The encapsulation header of CDR, little-endian (representation id 0x0001, options 0).
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

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

/// A CDR message being written into a reused buffer.
#[derive(Debug)]
pub struct Cdr<'a> {
    buf: &'a mut Vec<u8>,
}

impl<'a> Cdr<'a> {
    /// Starts a message in `buf` (cleared): the encapsulation header.
    pub fn new(buf: &'a mut Vec<u8>) -> Self {
        buf.clear();
        buf.extend_from_slice(&CDR_LE);
        Self { buf }
    }

    /// Pads to a multiple of `n` bytes from the end of the header.
    fn align(&mut self, n: usize) {
        while !(self.buf.len() - CDR_LE.len()).is_multiple_of(n) {
            self.buf.push(0);
        }
    }

    /// A `uint32`.
    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// An `int32`.
    pub fn i32(&mut self, v: i32) -> &mut Self {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// A `float64`.
    pub fn f64(&mut self, v: f64) -> &mut Self {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }

    /// A `string` (no NUL inside: one is cut there, as a C reader would).
    pub fn string(&mut self, s: &str) -> &mut Self {
        let s = s.split('\0').next().unwrap_or("");
        self.u32(u32::try_from(s.len() + 1).unwrap_or(u32::MAX));
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
        self
    }

    /// A sequence's element count.
    pub fn count(&mut self, n: usize) -> &mut Self {
        self.u32(u32::try_from(n).unwrap_or(u32::MAX))
    }

    /// A `float64[]`.
    pub fn f64s(&mut self, values: impl ExactSizeIterator<Item = f64>) -> &mut Self {
        self.count(values.len());
        for v in values {
            self.f64(v);
        }
        self
    }

    /// A `builtin_interfaces/Time` of `ns` nanoseconds.
    pub fn time(&mut self, ns: u64) -> &mut Self {
        self.i32(i32::try_from(ns / 1_000_000_000).unwrap_or(i32::MAX));
        self.u32(u32::try_from(ns % 1_000_000_000).unwrap_or(0))
    }
}

/// `std_msgs/msg/String` `{ data: text }` into `buf`.
pub fn encode_string(buf: &mut Vec<u8>, text: &str) {
    Cdr::new(buf).string(text);
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
    let mut c = Cdr::new(buf);
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
    fn a_string_is_its_length_with_the_nul_then_its_bytes() {
        let mut buf = Vec::new();
        encode_string(&mut buf, "hi");
        assert_eq!(buf, [0, 1, 0, 0, 3, 0, 0, 0, b'h', b'i', 0]);
    }

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
