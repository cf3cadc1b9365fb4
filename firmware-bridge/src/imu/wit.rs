//! WIT Motion standard serial protocol (WT901, HWT905, JY901 and their many OEM copies): the AHRS
//! output format most small legged robots buy first.
//!
//! Every packet is 11 bytes: `0x55, TYPE, D0..D7, SUM`, where SUM is the low byte of the sum of the
//! first ten bytes and D0..D7 are four little-endian `i16`. Types used here:
//! `0x51` acceleration (÷32768 × 16 g) + temperature (÷100 °C), `0x52` angular velocity
//! (÷32768 × 2000 °/s) + voltage (÷100 V), `0x53` roll/pitch/yaw (÷32768 × 180°) + version,
//! `0x59` quaternion w, x, y, z (÷32768). One output cycle sends the enabled types in that order.

use std::f64::consts::PI;

/// Packet header byte.
pub const HEADER: u8 = 0x55;
/// Bytes per packet.
pub const PACKET_LEN: usize = 11;
/// Standard gravity used by the accelerometer scale, m/s².
pub const G: f64 = 9.80665;

/// Packet types.
pub mod kind {
    /// Acceleration and temperature.
    pub const ACCEL: u8 = 0x51;
    /// Angular velocity and voltage.
    pub const GYRO: u8 = 0x52;
    /// Euler angles and version.
    pub const ANGLE: u8 = 0x53;
    /// Quaternion.
    pub const QUATERNION: u8 = 0x59;
}

/// Full-scale ranges.
const ACCEL_FS: f64 = 16.0 * G;
const GYRO_FS: f64 = 2000.0 * PI / 180.0;

/// One step of the acceleration output, m/s².
pub const ACCEL_RESOLUTION: f64 = ACCEL_FS / 32768.0;
/// One step of the angular velocity output, rad/s.
pub const GYRO_RESOLUTION: f64 = GYRO_FS / 32768.0;
/// One step of a quaternion component.
pub const QUATERNION_RESOLUTION: f64 = 1.0 / 32768.0;

/// One complete output cycle, in SI units and the sensor's own axes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuSample {
    /// Specific force (what an accelerometer measures), m/s².
    pub accel: [f64; 3],
    /// Angular velocity, rad/s.
    pub gyro: [f64; 3],
    /// Orientation quaternion `[w, x, y, z]` (sensor to world).
    pub quat: [f64; 4],
    /// Roll, pitch, yaw, rad.
    pub rpy: [f64; 3],
    /// Chip temperature, °C.
    pub temperature: f64,
}

fn scale_to_i16(value: f64, full_scale: f64) -> i16 {
    (value / full_scale * 32768.0).round().clamp(-32768.0, 32767.0) as i16
}

fn from_i16(raw: i16, full_scale: f64) -> f64 {
    f64::from(raw) / 32768.0 * full_scale
}

/// Writes one packet of `kind` with four values into `out`.
pub fn encode(kind: u8, values: [i16; 4], out: &mut [u8; PACKET_LEN]) {
    out[0] = HEADER;
    out[1] = kind;
    for (i, v) in values.iter().enumerate() {
        out[2 + 2 * i..4 + 2 * i].copy_from_slice(&v.to_le_bytes());
    }
    out[10] = out[..10].iter().fold(0u8, |s, &b| s.wrapping_add(b));
}

/// Encodes one output cycle (accel, gyro, angle, quaternion) of `s` into `out` (44 bytes).
pub fn encode_cycle(s: &ImuSample, out: &mut [u8; 4 * PACKET_LEN]) {
    let mut p = [0u8; PACKET_LEN];
    let a = s.accel.map(|v| scale_to_i16(v, ACCEL_FS));
    encode(
        kind::ACCEL,
        [a[0], a[1], a[2], (s.temperature * 100.0).round() as i16],
        &mut p,
    );
    out[..11].copy_from_slice(&p);
    let g = s.gyro.map(|v| scale_to_i16(v, GYRO_FS));
    encode(kind::GYRO, [g[0], g[1], g[2], 1200], &mut p);
    out[11..22].copy_from_slice(&p);
    let r = s.rpy.map(|v| scale_to_i16(v, PI));
    encode(kind::ANGLE, [r[0], r[1], r[2], 0x0106], &mut p);
    out[22..33].copy_from_slice(&p);
    let q = s.quat.map(|v| scale_to_i16(v, 1.0));
    encode(kind::QUATERNION, q, &mut p);
    out[33..].copy_from_slice(&p);
}

/// Counters of a decoder.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Packets with a good checksum.
    pub packets: u64,
    /// Packets dropped for a bad checksum.
    pub checksum_errors: u64,
    /// Bytes skipped while looking for a header.
    pub junk_bytes: u64,
    /// Good packets of a type this decoder does not use.
    pub unknown_types: u64,
    /// Complete samples.
    pub samples: u64,
}

/// Streaming decoder: feed bytes as they come, get a sample per completed output cycle.
///
/// A sample is complete when acceleration, angular velocity and quaternion have all arrived since
/// the last one (the angle packet is used when present).
#[derive(Debug, Clone, Default)]
pub struct WitDecoder {
    buf: [u8; PACKET_LEN],
    len: usize,
    current: ImuSample,
    have: u8,
    stats: DecoderStats,
}

const HAVE_ACCEL: u8 = 1;
const HAVE_GYRO: u8 = 2;
const HAVE_QUAT: u8 = 4;

impl WitDecoder {
    /// A decoder waiting for a header.
    pub fn new() -> Self {
        Self::default()
    }

    /// Counters.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Feeds `bytes`; calls `on_sample` for every sample they complete.
    pub fn feed(&mut self, bytes: &[u8], mut on_sample: impl FnMut(&ImuSample)) {
        for &b in bytes {
            if self.len == 0 && b != HEADER {
                self.stats.junk_bytes += 1;
                continue;
            }
            self.buf[self.len] = b;
            self.len += 1;
            if self.len < PACKET_LEN {
                continue;
            }
            let sum = self.buf[..10].iter().fold(0u8, |s, &x| s.wrapping_add(x));
            if sum != self.buf[10] {
                self.stats.checksum_errors += 1;
                // Resynchronise on the next header inside the rejected bytes.
                let next = self.buf[1..]
                    .iter()
                    .position(|&x| x == HEADER)
                    .map_or(PACKET_LEN, |p| p + 1);
                self.stats.junk_bytes += next as u64;
                self.buf.copy_within(next.., 0);
                self.len = PACKET_LEN - next;
                continue;
            }
            self.len = 0;
            self.stats.packets += 1;
            if self.apply() && self.have == HAVE_ACCEL | HAVE_GYRO | HAVE_QUAT {
                self.have = 0;
                self.stats.samples += 1;
                on_sample(&self.current);
            }
        }
    }

    fn apply(&mut self) -> bool {
        let v: [i16; 4] =
            std::array::from_fn(|i| i16::from_le_bytes([self.buf[2 + 2 * i], self.buf[3 + 2 * i]]));
        let s = &mut self.current;
        match self.buf[1] {
            kind::ACCEL => {
                s.accel = [0, 1, 2].map(|i| from_i16(v[i], ACCEL_FS));
                s.temperature = f64::from(v[3]) / 100.0;
                self.have |= HAVE_ACCEL;
            }
            kind::GYRO => {
                s.gyro = [0, 1, 2].map(|i| from_i16(v[i], GYRO_FS));
                self.have |= HAVE_GYRO;
            }
            kind::ANGLE => s.rpy = [0, 1, 2].map(|i| from_i16(v[i], PI)),
            kind::QUATERNION => {
                s.quat = v.map(|x| from_i16(x, 1.0));
                self.have |= HAVE_QUAT;
            }
            _ => {
                self.stats.unknown_types += 1;
                return false;
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_known_packet_decodes_to_the_datasheet_values() {
        // Acceleration packet: ax = 0, ay = 0, az = 0x0800 (1 g), T = 0x0A28 (26.00 °C).
        let bytes = [0x55, 0x51, 0x00, 0x00, 0x00, 0x00, 0x00, 0x08, 0x28, 0x0A, 0x00];
        let mut p = bytes;
        p[10] = p[..10].iter().fold(0u8, |s, &b| s.wrapping_add(b));
        assert_eq!(
            p[10],
            0x55u8
                .wrapping_add(0x51)
                .wrapping_add(0x08)
                .wrapping_add(0x28)
                .wrapping_add(0x0A)
        );
        let mut enc = [0u8; PACKET_LEN];
        encode(kind::ACCEL, [0, 0, 0x0800, 0x0A28], &mut enc);
        assert_eq!(enc, p);
        let mut d = WitDecoder::new();
        d.feed(&p, |_| panic!("an accel packet alone is no sample"));
        assert!((d.current.accel[2] - G).abs() < 1e-9 && (d.current.temperature - 26.0).abs() < 1e-9);
    }

    #[test]
    fn cycles_round_trip_within_quantisation_and_garbage_is_skipped() {
        let s = ImuSample {
            accel: [0.3, -0.2, 9.81],
            gyro: [0.5, -1.0, 0.25],
            quat: [0.9990, 0.0, 0.0447, 0.0],
            rpy: [0.0, 0.0894, 0.0],
            temperature: 31.5,
        };
        let mut cycle = [0u8; 44];
        encode_cycle(&s, &mut cycle);
        let mut stream = vec![0x00, 0x55, 0x13, 0xFF];
        stream.extend_from_slice(&cycle);
        let mut corrupt = cycle;
        corrupt[5] ^= 0x40;
        stream.extend_from_slice(&corrupt);
        stream.extend_from_slice(&cycle);
        let mut out = Vec::new();
        let mut d = WitDecoder::new();
        d.feed(&stream, |x| out.push(*x));
        assert_eq!(out.len(), 2, "{:?}", d.stats());
        for got in &out {
            for i in 0..3 {
                assert!((got.accel[i] - s.accel[i]).abs() < ACCEL_FS / 32768.0);
                assert!((got.gyro[i] - s.gyro[i]).abs() < GYRO_FS / 32768.0);
            }
            assert!((got.quat[2] - s.quat[2]).abs() < 1.0 / 32768.0);
        }
        // The corrupted packet, and the false header (0x55) in the leading junk.
        assert_eq!(d.stats().checksum_errors, 2);
    }

    #[test]
    fn random_bytes_never_panic() {
        let mut rng = crate::time::SimRng::new(3);
        let mut d = WitDecoder::new();
        for _ in 0..20_000 {
            let b = if rng.chance(0.2) {
                HEADER
            } else {
                rng.next_u64() as u8
            };
            d.feed(&[b], |_| {});
        }
        assert!(d.stats().junk_bytes > 0);
    }
}
