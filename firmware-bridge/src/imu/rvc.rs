//! BNO08x (BNO080/085/086) in UART-RVC mode: the chip streams its fused attitude and acceleration
//! at 100 Hz, 115200 baud, with no host commands.
//!
//! Every frame is 19 bytes: `AA AA`, an index (0–255, rising), yaw, pitch, roll (little-endian
//! `i16`, 0.01°), x, y, z acceleration (`i16`, mg, gravity included), three reserved bytes
//! (motion intent, motion request, reserved), and a checksum: the low byte of the sum of the
//! index through the reserved bytes. The angles are Tait–Bryan z-y-x (yaw, then pitch, then
//! roll). RVC reports no angular velocity: the decoder derives it from consecutive attitudes
//! (their relative rotation over the 10 ms frame period), so a missed frame costs one sample.

use super::wit::{DecoderStats, G, ImuSample};

/// Frame header bytes.
pub const HEADER: [u8; 2] = [0xAA, 0xAA];
/// Bytes per frame.
pub const FRAME_LEN: usize = 19;
/// The chip's fixed output rate, Hz.
pub const RATE_HZ: f64 = 100.0;
/// The chip's fixed line speed, baud.
pub const BAUD: u32 = 115_200;
/// One step of an angle, rad.
pub const ANGLE_RESOLUTION: f64 = 0.01 * std::f64::consts::PI / 180.0;
/// One step of an acceleration, m/s².
pub const ACCEL_RESOLUTION: f64 = G / 1000.0;

/// Encodes one frame: `index`, the attitude as yaw/pitch/roll (rad) and the acceleration (m/s²).
pub fn encode(index: u8, ypr: [f64; 3], accel: [f64; 3]) -> [u8; FRAME_LEN] {
    let mut f = [0u8; FRAME_LEN];
    f[..2].copy_from_slice(&HEADER);
    f[2] = index;
    let angle = |a: f64| (a / ANGLE_RESOLUTION).round().clamp(-32768.0, 32767.0) as i16;
    let mg = |a: f64| (a / ACCEL_RESOLUTION).round().clamp(-32768.0, 32767.0) as i16;
    for (k, v) in ypr
        .iter()
        .map(|&a| angle(a))
        .chain(accel.iter().map(|&a| mg(a)))
        .enumerate()
    {
        f[3 + 2 * k..5 + 2 * k].copy_from_slice(&v.to_le_bytes());
    }
    f[18] = checksum(&f);
    f
}

/// The checksum of a frame: the low byte of the sum of bytes 2..=17.
pub fn checksum(frame: &[u8; FRAME_LEN]) -> u8 {
    frame[2..18].iter().fold(0u8, |s, &b| s.wrapping_add(b))
}

/// One decoded frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RvcFrame {
    /// Rising index (wraps at 255).
    pub index: u8,
    /// Yaw, pitch, roll, rad.
    pub ypr: [f64; 3],
    /// Acceleration, m/s².
    pub accel: [f64; 3],
}

/// Decodes a frame whose checksum is right.
pub fn decode(frame: &[u8; FRAME_LEN]) -> Option<RvcFrame> {
    if frame[..2] != HEADER || checksum(frame) != frame[18] {
        return None;
    }
    let v = |k: usize| f64::from(i16::from_le_bytes([frame[3 + 2 * k], frame[4 + 2 * k]]));
    Some(RvcFrame {
        index: frame[2],
        ypr: [0, 1, 2].map(|k| v(k) * ANGLE_RESOLUTION),
        accel: [3, 4, 5].map(|k| v(k) * ACCEL_RESOLUTION),
    })
}

/// The quaternion `[w, x, y, z]` of yaw, pitch, roll (z-y-x).
pub fn quat_of_ypr(ypr: [f64; 3]) -> [f64; 4] {
    let q = glam::DQuat::from_euler(glam::EulerRot::ZYX, ypr[0], ypr[1], ypr[2]);
    [q.w, q.x, q.y, q.z]
}

/// Yaw, pitch, roll (z-y-x) of the quaternion `[w, x, y, z]`.
pub fn ypr_of_quat(q: [f64; 4]) -> [f64; 3] {
    let (yaw, pitch, roll) = glam::DQuat::from_xyzw(q[1], q[2], q[3], q[0]).to_euler(glam::EulerRot::ZYX);
    [yaw, pitch, roll]
}

/// Frames out of a byte stream: resynchronises on the header, drops frames with a bad checksum,
/// derives the angular velocity from consecutive frames.
#[derive(Debug, Default)]
pub struct RvcDecoder {
    frame: [u8; FRAME_LEN],
    have: usize,
    previous: Option<(u8, [f64; 4])>,
    stats: DecoderStats,
}

impl RvcDecoder {
    /// A decoder waiting for a header.
    pub fn new() -> Self {
        Self::default()
    }

    /// Counters.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Takes `bytes`, calling `on_sample` for each good frame.
    pub fn feed(&mut self, bytes: &[u8], mut on_sample: impl FnMut(&ImuSample)) {
        self.feed_dyn(bytes, &mut on_sample);
    }

    fn feed_dyn(&mut self, bytes: &[u8], on_sample: &mut dyn FnMut(&ImuSample)) {
        for &b in bytes {
            // The header: both bytes AA; anything else before it is junk.
            if self.have < 2 {
                if b == HEADER[0] {
                    self.frame[self.have] = b;
                    self.have += 1;
                } else {
                    self.stats.junk_bytes += 1 + self.have as u64;
                    self.have = 0;
                }
                continue;
            }
            self.frame[self.have] = b;
            self.have += 1;
            if self.have < FRAME_LEN {
                continue;
            }
            self.have = 0;
            let Some(f) = decode(&self.frame) else {
                self.stats.checksum_errors += 1;
                // A bad frame may have been a misaligned one: look for a header inside it.
                if let Some(at) = (1..FRAME_LEN - 1).find(|&i| self.frame[i..i + 2] == HEADER) {
                    let rest = self.frame;
                    self.feed_dyn(&rest[at..], on_sample);
                }
                continue;
            };
            self.stats.packets += 1;
            let quat = quat_of_ypr(f.ypr);
            let gyro = match self.previous {
                // Consecutive frames only: 10 ms apart.
                Some((index, prev)) if index.wrapping_add(1) == f.index => {
                    body_rate(prev, quat, 1.0 / RATE_HZ)
                }
                _ => [0.0; 3],
            };
            self.previous = Some((f.index, quat));
            self.stats.samples += 1;
            on_sample(&ImuSample {
                accel: f.accel,
                gyro,
                quat,
                rpy: [f.ypr[2], f.ypr[1], f.ypr[0]],
                temperature: f64::NAN,
            });
        }
    }
}

/// The body-frame angular velocity that turns `from` into `to` in `dt` seconds.
fn body_rate(from: [f64; 4], to: [f64; 4], dt: f64) -> [f64; 3] {
    let a = glam::DQuat::from_xyzw(from[1], from[2], from[3], from[0]);
    let b = glam::DQuat::from_xyzw(to[1], to[2], to[3], to[0]);
    let rel = a.conjugate() * b;
    let rel = if rel.w < 0.0 { -rel } else { rel };
    let v = rel.to_scaled_axis() / dt;
    [v.x, v.y, v.z]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The frame the BNO08x datasheet gives as its UART-RVC example.
    const DATASHEET_FRAME: [u8; FRAME_LEN] = [
        0xAA, 0xAA, 0xDE, 0x01, 0x00, 0x92, 0xFF, 0x25, 0x08, 0x8D, 0xFE, 0xEC, 0xFF, 0xD1, 0x03, 0x00, 0x00,
        0x00, 0xE7,
    ];

    #[test]
    fn the_datasheet_frame_decodes_to_its_published_values() {
        let f = decode(&DATASHEET_FRAME).unwrap();
        assert_eq!(f.index, 0xDE);
        let deg = f.ypr.map(f64::to_degrees);
        assert!(
            (deg[0] - 0.01).abs() < 1e-9 && (deg[1] + 1.10).abs() < 1e-9 && (deg[2] - 20.85).abs() < 1e-9,
            "{deg:?}"
        );
        let mg = f.accel.map(|a| a / ACCEL_RESOLUTION);
        assert!(
            (mg[0] + 371.0).abs() < 1e-9 && (mg[1] + 20.0).abs() < 1e-9 && (mg[2] - 977.0).abs() < 1e-9,
            "{mg:?}"
        );
        // And it re-encodes byte for byte.
        assert_eq!(encode(f.index, f.ypr, f.accel), DATASHEET_FRAME);
        let mut bad = DATASHEET_FRAME;
        bad[10] ^= 1;
        assert!(decode(&bad).is_none());
    }

    #[test]
    fn the_decoder_resynchronises_and_derives_the_turn_rate() {
        let mut bytes = vec![0x12, 0xAA, 0x34];
        // Turning about z at 1 rad/s: 0.01 rad a frame.
        for k in 0..20u8 {
            bytes.extend_from_slice(&encode(k, [0.01 * f64::from(k), 0.0, 0.0], [0.0, 0.0, G]));
            if k == 7 {
                bytes.extend_from_slice(&[0xAA, 0xAA, 0x00]);
            }
        }
        let mut d = RvcDecoder::new();
        let mut samples = Vec::new();
        d.feed(&bytes, |s| samples.push(*s));
        assert!(samples.len() >= 18, "{} samples, {:?}", samples.len(), d.stats());
        let rate = samples.last().unwrap().gyro[2];
        // One angle step (0.01°) over a frame period is 0.017 rad/s.
        assert!((rate - 1.0).abs() < 0.02, "{rate}");
        assert!((samples[5].accel[2] - G).abs() < ACCEL_RESOLUTION);
    }
}
