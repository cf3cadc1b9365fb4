//! How long a classic CAN frame occupies the wire, bit-exactly: the frame's fields are laid out as
//! transmitted, the CRC-15 is computed, and stuff bits are counted over SOF..CRC the way a CAN
//! controller inserts them (a complement bit after five equal bits, counting stuff bits in runs).

use std::time::Duration;

use super::{CanFrame, CanId};

/// Bits after the CRC that are never stuffed: CRC delimiter, ACK slot, ACK delimiter, 7-bit EOF,
/// and the 3-bit intermission before the next frame may start.
const UNSTUFFED_TAIL_BITS: u32 = 1 + 1 + 1 + 7 + 3;

/// A fixed-capacity bit buffer: the longest stuffable span is 54 + 64 + 15 bits.
struct Bits {
    bits: [bool; 160],
    len: usize,
}

impl Bits {
    fn push(&mut self, value: u32, width: u32) {
        for i in (0..width).rev() {
            self.bits[self.len] = (value >> i) & 1 == 1;
            self.len += 1;
        }
    }
}

fn crc15(bits: &[bool]) -> u32 {
    // CAN CRC-15, polynomial x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1 (0x4599), init 0.
    let mut crc: u32 = 0;
    for &bit in bits {
        let next = u32::from(bit) ^ ((crc >> 14) & 1);
        crc = (crc << 1) & 0x7FFF;
        if next == 1 {
            crc ^= 0x4599;
        }
    }
    crc
}

/// Number of bits `frame` occupies on the wire, stuff bits and interframe space included.
pub fn frame_bits(frame: &CanFrame) -> u32 {
    let mut b = Bits {
        bits: [false; 160],
        len: 0,
    };
    b.push(0, 1); // SOF (dominant)
    match frame.id() {
        CanId::Standard(id) => {
            b.push(u32::from(id), 11);
            b.push(0, 1); // RTR: data frame
            b.push(0, 1); // IDE: standard
            b.push(0, 1); // r0
        }
        CanId::Extended(id) => {
            b.push(id >> 18, 11);
            b.push(1, 1); // SRR
            b.push(1, 1); // IDE: extended
            b.push(id & 0x3FFFF, 18);
            b.push(0, 1); // RTR
            b.push(0, 2); // r1, r0
        }
    }
    b.push(frame.dlc() as u32, 4);
    for &byte in frame.data() {
        b.push(u32::from(byte), 8);
    }
    let crc = crc15(&b.bits[..b.len]);
    b.push(crc, 15);

    let mut stuffed = 0;
    let (mut run_value, mut run_len) = (b.bits[0], 0u32);
    for &bit in &b.bits[..b.len] {
        if bit == run_value {
            run_len += 1;
        } else {
            run_value = bit;
            run_len = 1;
        }
        if run_len == 5 {
            // The inserted complement bit starts a new run of its own value.
            stuffed += 1;
            run_value = !run_value;
            run_len = 1;
        }
    }
    b.len as u32 + stuffed + UNSTUFFED_TAIL_BITS
}

/// The most bits a data frame of `dlc` bytes can occupy (every stuff bit the rule allows, since
/// the data decide how many there are): what a schedule must budget for.
pub const fn worst_case_bits(dlc: u8, extended: bool) -> u32 {
    // SOF, identifier and control bits, data, CRC-15: the span stuff bits are inserted into.
    let header = if extended {
        1 + 11 + 2 + 18 + 3 + 4
    } else {
        1 + 11 + 3 + 4
    };
    let span = header + 8 * dlc as u32 + 15;
    // A stuff bit follows every 5 equal bits; each inserted bit starts a new run, so at most one
    // per 4 bits after the first.
    span + (span - 1) / 4 + UNSTUFFED_TAIL_BITS
}

/// Time `frame` occupies a bus running at `bitrate` bit/s.
pub fn frame_time(frame: &CanFrame, bitrate: u32) -> Duration {
    bits_time(frame_bits(frame), bitrate)
}

/// Time `bits` occupy a bus running at `bitrate` bit/s.
pub fn bits_time(bits: u32, bitrate: u32) -> Duration {
    Duration::from_nanos(u64::from(bits) * 1_000_000_000 / u64::from(bitrate.max(1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_frame_is_longer_than_its_worst_case() {
        // Payloads that stuff the most: runs of equal bits through data and identifier.
        for data in [
            [0u8; 8],
            [0xFF; 8],
            [0x0F; 8],
            [0xF0; 8],
            [0x83, 0xE0, 0xF8, 0x3E, 0x0F, 0x83, 0xE0, 0xF8],
        ] {
            for id in [0u16, 0x7FF, 0x001, 0x400] {
                let f = CanFrame::new8(CanId::Standard(id), data);
                assert!(frame_bits(&f) <= worst_case_bits(8, false), "{id:#x} {data:?}");
            }
        }
        // 8-byte standard frame: 98 stuffable bits, at most 24 stuff bits, 13 unstuffed.
        assert_eq!(worst_case_bits(8, false), 135);
        assert_eq!(worst_case_bits(0, false), 34 + 8 + 13);
    }

    #[test]
    fn crc15_leaves_zero_remainder_over_message_and_crc() {
        // A zero-init, non-reflected CRC divides message·x^15 + crc exactly: this is how the
        // receiving controller checks a frame.
        let mut rng = crate::time::SimRng::new(3);
        for _ in 0..200 {
            let n = 1 + (rng.next_u64() % 100) as usize;
            let mut bits: Vec<bool> = (0..n).map(|_| rng.next_u64() & 1 == 1).collect();
            let crc = crc15(&bits);
            assert!(crc < 0x8000);
            bits.extend((0..15).rev().map(|i| (crc >> i) & 1 == 1));
            assert_eq!(crc15(&bits), 0);
        }
        // A single bit flip is always detected.
        let bits = [true, false, true, true, false, false, true];
        let mut flipped = bits;
        flipped[3] = !flipped[3];
        assert_ne!(crc15(&bits), crc15(&flipped));
    }

    #[test]
    fn eight_byte_standard_frames_take_111_to_135_bits() {
        let id = CanId::standard(0x001).unwrap();
        // Unstuffed length: 1 + 11 + 3 + 4 + 64 + 15 = 98, plus 13 tail bits = 111.
        let alternating = CanFrame::new8(id, [0x55; 8]);
        let worst = CanFrame::new8(CanId::standard(0).unwrap(), [0; 8]);
        let a = frame_bits(&alternating);
        let w = frame_bits(&worst);
        assert!((111..=120).contains(&a), "alternating data: {a} bits");
        assert!(w > a && w <= 135, "all-zero frame: {w} bits");
        // 1 Mbit/s: about 0.11–0.135 ms per frame, as the protocol notes say.
        let t = frame_time(&worst, 1_000_000);
        assert!(
            t >= Duration::from_micros(111) && t <= Duration::from_micros(135),
            "{t:?}"
        );
    }

    #[test]
    fn extended_frames_are_longer() {
        let s = CanFrame::new8(CanId::standard(0x123).unwrap(), [0xA5; 8]);
        let e = CanFrame::new8(CanId::extended(0x123).unwrap(), [0xA5; 8]);
        assert!(frame_bits(&e) >= frame_bits(&s) + 20);
    }
}
