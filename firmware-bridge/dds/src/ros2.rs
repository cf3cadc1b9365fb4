//! ROS 2's messages in their CDR, as ROS 2's DDS middlewares put them on the wire (and MCAP
//! files with the `cdr` encoding carry them): the ones a robot's run publishes — its description
//! (`std_msgs/msg/String`), joints (`sensor_msgs/msg/JointState`), frames (`tf2_msgs/msg/TFMessage`)
//! and health (`diagnostic_msgs/msg/DiagnosticArray`), and a simulation's time
//! (`rosgraph_msgs/msg/Clock`) — and the one it takes, a velocity command
//! (`geometry_msgs/msg/Twist`).

use crate::cdr::{CdrError, CdrReader, CdrWriter};

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

/// One transform of a `tf2_msgs/msg/TFMessage`: `child` in `parent`, translation (m) and
/// rotation (`[x, y, z, w]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform<'a> {
    /// The frame it is in.
    pub parent: &'a str,
    /// The frame it places.
    pub child: &'a str,
    /// Translation, m.
    pub translation: [f64; 3],
    /// Rotation `[x, y, z, w]`.
    pub rotation: [f64; 4],
}

/// A `tf2_msgs/msg/TFMessage` of `transforms`, all stamped `stamp_ns`, into `buf`.
pub fn encode_tf<'a>(
    buf: &mut Vec<u8>,
    stamp_ns: u64,
    transforms: impl ExactSizeIterator<Item = Transform<'a>>,
) {
    let mut c = CdrWriter::new(buf);
    c.count(transforms.len());
    for t in transforms {
        // geometry_msgs/TransformStamped: header, child_frame_id, transform.
        c.time(stamp_ns).string(t.parent).string(t.child);
        for v in t.translation.into_iter().chain(t.rotation) {
            c.f64(v);
        }
    }
}

/// A `diagnostic_msgs/msg/DiagnosticStatus` level.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// 0.
    Ok = 0,
    /// 1.
    Warn = 1,
    /// 2.
    Error = 2,
    /// 3.
    Stale = 3,
}

/// One `diagnostic_msgs/msg/DiagnosticStatus`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Status<'a> {
    /// How it is.
    pub level: Level,
    /// What it is about (`robodeploy: loop`).
    pub name: &'a str,
    /// In words.
    pub message: &'a str,
    /// The device (a robot's name, a bus).
    pub hardware_id: &'a str,
    /// Key-value pairs.
    pub values: &'a [(&'a str, &'a str)],
}

/// A `diagnostic_msgs/msg/DiagnosticArray` of `statuses`, stamped `stamp_ns`, into `buf`.
pub fn encode_diagnostics(buf: &mut Vec<u8>, stamp_ns: u64, statuses: &[Status<'_>]) {
    let mut c = CdrWriter::new(buf);
    c.time(stamp_ns).string("").count(statuses.len());
    for s in statuses {
        c.u8(s.level as u8)
            .string(s.name)
            .string(s.message)
            .string(s.hardware_id)
            .count(s.values.len());
        for (k, v) in s.values {
            c.string(k).string(v);
        }
    }
}

/// A `rosgraph_msgs/msg/Clock` at `stamp_ns` (the time nodes with `use_sim_time` follow), into
/// `buf`.
pub fn encode_clock(buf: &mut Vec<u8>, stamp_ns: u64) {
    CdrWriter::new(buf).time(stamp_ns);
}

/// A `geometry_msgs/msg/Twist`'s CDR, header included, bytes.
pub const TWIST_BYTES: usize = 4 + 6 * 8;

/// A `geometry_msgs/msg/Twist`: linear (m/s) then angular (rad/s) velocity, x y z each.
pub fn decode_twist(sample: &[u8]) -> Result<[f64; 6], CdrError> {
    // Six doubles behind the encapsulation header, nothing else: a longer sample is another type.
    if sample.len() != TWIST_BYTES {
        return Err(CdrError::Length {
            expected: TWIST_BYTES,
            found: sample.len(),
        });
    }
    let mut r = CdrReader::new(sample)?;
    let mut out = [0.0; 6];
    for v in &mut out {
        *v = r.f64()?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_twist_is_exactly_six_doubles_and_a_blob_is_not_one() {
        let mut sample = vec![0x00, 0x01, 0x00, 0x00];
        for v in [0.5f64, 0.0, 0.0, 0.0, 0.0, -0.25] {
            sample.extend_from_slice(&v.to_le_bytes());
        }
        assert_eq!(decode_twist(&sample), Ok([0.5, 0.0, 0.0, 0.0, 0.0, -0.25]));
        // A megabyte published under the Twist type: refused, not read as its first 48 bytes.
        let mut blob = sample.clone();
        blob.resize(1 << 20, 0xff);
        assert_eq!(
            decode_twist(&blob),
            Err(CdrError::Length {
                expected: TWIST_BYTES,
                found: 1 << 20
            })
        );
        assert!(decode_twist(&sample[..40]).is_err());
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

    #[test]
    fn a_transform_is_its_header_child_then_seven_doubles() {
        let mut buf = Vec::new();
        let t = Transform {
            parent: "world",
            child: "pelvis",
            translation: [1.0, 2.0, 3.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        encode_tf(&mut buf, 2_000_000_001, [t].into_iter());
        let body = &buf[4..];
        assert_eq!(&body[..4], [1, 0, 0, 0]);
        // stamp 2 s 1 ns; "world\0" (6) at 16..22; "pelvis\0" (7) at 28..35; doubles from 40.
        assert_eq!(&body[4..12], [2, 0, 0, 0, 1, 0, 0, 0]);
        assert_eq!(&body[12..16], [6, 0, 0, 0]);
        assert_eq!(&body[16..22], b"world\0");
        assert_eq!(&body[24..28], [7, 0, 0, 0]);
        assert_eq!(&body[28..35], b"pelvis\0");
        assert_eq!(&body[40..48], 1.0f64.to_le_bytes());
        assert_eq!(&body[88..96], 1.0f64.to_le_bytes());
        assert_eq!(body.len(), 96);
    }

    #[test]
    fn a_twist_reads_back_and_a_short_one_is_refused() {
        let mut buf = Vec::new();
        let mut w = CdrWriter::new(&mut buf);
        for v in [0.5, 0.0, 0.0, 0.0, 0.0, -0.25] {
            w.f64(v);
        }
        assert_eq!(decode_twist(&buf), Ok([0.5, 0.0, 0.0, 0.0, 0.0, -0.25]));
        assert!(decode_twist(&buf[..40]).is_err());
    }
}
