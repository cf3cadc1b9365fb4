//! How long a classic CAN frame occupies the wire, bit-exactly: the frame's fields are laid out as
//! transmitted, the CRC-15 is computed, and stuff bits are counted over SOF..CRC the way a CAN
//! controller inserts them (a complement bit after five equal bits, counting stuff bits in runs).

use std::time::Duration;

use super::{CanFrame, CanId};

/// Bits after the CRC that are never stuffed: CRC delimiter, ACK slot, ACK delimiter, 7-bit EOF,
/// and the 3-bit intermission before the next frame may start.
const UNSTUFFED_TAIL_BITS: u32 = 1 + 1 + 1 + 7 + 3;

/// The stuffable span of a data frame, SOF..CRC (at most 39 + 64 + 15 = 118 bits, an extended
/// frame's), most significant bit first.
struct Bits {
    word: u128,
    len: u32,
}

impl Bits {
    fn push(&mut self, value: u32, width: u32) {
        self.word = (self.word << width) | u128::from(value & ((1u64 << width) - 1) as u32);
        self.len += width;
    }

    /// Folds the bits in transmission order into `acc`: eight at a time through `byte`, the
    /// rest one by one through `bit`.
    fn fold<A>(&self, mut acc: A, byte: impl Fn(A, u8) -> A, bit: impl Fn(A, bool) -> A) -> A {
        let mut left = self.len;
        while left >= 8 {
            acc = byte(acc, (self.word >> (left - 8)) as u8);
            left -= 8;
        }
        while left > 0 {
            acc = bit(acc, (self.word >> (left - 1)) & 1 == 1);
            left -= 1;
        }
        acc
    }
}

/// CAN's CRC-15 polynomial x^15 + x^14 + x^10 + x^8 + x^7 + x^4 + x^3 + 1.
const CRC15_POLY: u32 = 0x4599;

/// One bit into the CRC-15 register (zero-initialised, not reflected).
const fn crc15_bit(crc: u32, bit: bool) -> u32 {
    let next = (bit as u32) ^ ((crc >> 14) & 1);
    let crc = (crc << 1) & 0x7FFF;
    if next == 1 { crc ^ CRC15_POLY } else { crc }
}

/// The register after eight bits, for every byte that meets the register's top eight bits.
const CRC15_BYTES: [u16; 256] = {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u32) << 7;
        let mut k = 0;
        while k < 8 {
            crc = crc15_bit(crc, false);
            k += 1;
        }
        table[i] = crc as u16;
        i += 1;
    }
    table
};

/// CRC-15 of `bits` in transmission order, eight bits at a time where it can.
fn crc15(bits: &Bits) -> u32 {
    bits.fold(
        0,
        |crc, byte| {
            let top = ((crc >> 7) ^ u32::from(byte)) & 0xFF;
            ((crc << 8) ^ u32::from(CRC15_BYTES[top as usize])) & 0x7FFF
        },
        crc15_bit,
    )
}

/// The stuffing state: the level of the current run and its length so far (0–4; 0 only before
/// the first bit), packed as `level · 5 + length`.
const STUFF_STATES: usize = 10;

/// One bit through the stuffing rule: the next state, and whether a stuff bit followed it (after
/// five equal bits the controller inserts their complement, which starts a run of its own).
const fn stuff_bit(state: usize, bit: bool) -> (usize, bool) {
    let (level, length) = (state / 5 == 1, state % 5);
    let length = if bit == level { length + 1 } else { 1 };
    if length == 5 {
        ((!bit as usize) * 5 + 1, true)
    } else {
        ((bit as usize) * 5 + length, false)
    }
}

/// For every state and byte: the state after the byte's eight bits and the stuff bits inserted.
const STUFF_BYTES: [[(u8, u8); 256]; STUFF_STATES] = {
    let mut table = [[(0u8, 0u8); 256]; STUFF_STATES];
    let mut state = 0;
    while state < STUFF_STATES {
        let mut byte = 0;
        while byte < 256 {
            let (mut s, mut stuffed, mut k) = (state, 0u8, 0);
            while k < 8 {
                let (next, inserted) = stuff_bit(s, (byte >> (7 - k)) & 1 == 1);
                s = next;
                stuffed += inserted as u8;
                k += 1;
            }
            table[state][byte] = (s as u8, stuffed);
            byte += 1;
        }
        state += 1;
    }
    table
};

/// Number of bits `frame` occupies on the wire, stuff bits and interframe space included. The
/// walk over the frame's bits is the virtual bus's dearest sum, so it goes a byte at a time.
pub fn frame_bits(frame: &CanFrame) -> u32 {
    let mut b = Bits { word: 0, len: 0 };
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
    let crc = crc15(&b);
    b.push(crc, 15);
    let (_, stuffed) = b.fold(
        (0usize, 0u32),
        |(state, stuffed), byte| {
            let (next, inserted) = STUFF_BYTES[state][usize::from(byte)];
            (usize::from(next), stuffed + u32::from(inserted))
        },
        |(state, stuffed), bit| {
            let (next, inserted) = stuff_bit(state, bit);
            (next, stuffed + u32::from(inserted))
        },
    );
    b.len + stuffed + UNSTUFFED_TAIL_BITS
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
        let bits_of = |v: &[bool]| {
            let mut b = Bits { word: 0, len: 0 };
            for &bit in v {
                b.push(u32::from(bit), 1);
            }
            b
        };
        let mut rng = crate::time::SimRng::new(3);
        for _ in 0..200 {
            let n = 1 + (rng.next_u64() % 100) as usize;
            let mut bits: Vec<bool> = (0..n).map(|_| rng.next_u64() & 1 == 1).collect();
            let crc = crc15(&bits_of(&bits));
            assert!(crc < 0x8000);
            // The table's bytes and the single bits agree.
            assert_eq!(crc, bits.iter().fold(0, |c, &b| crc15_bit(c, b)));
            bits.extend((0..15).rev().map(|i| (crc >> i) & 1 == 1));
            assert_eq!(crc15(&bits_of(&bits)), 0);
        }
        // A single bit flip is always detected.
        let bits = [true, false, true, true, false, false, true];
        let mut flipped = bits;
        flipped[3] = !flipped[3];
        assert_ne!(crc15(&bits_of(&bits)), crc15(&bits_of(&flipped)));
    }

    #[test]
    fn frames_take_the_bits_counted_bit_by_bit() {
        // Known vectors: identifiers and payloads drawn at random, their lengths counted by the
        // first implementation of this file, which laid the fields out one bool per bit and
        // walked the stuffing rule over them bit by bit.
        let cases: [(CanId, &[u8], u32); 12] = [
            (CanId::Extended(352606660), &[161, 109, 240], 96),
            (CanId::Standard(1888), &[100, 234, 118, 42], 80),
            (CanId::Standard(1603), &[75], 58),
            (CanId::Extended(325712248), &[], 70),
            (CanId::Standard(1854), &[84, 77, 70, 120, 157, 246, 229], 107),
            (CanId::Standard(758), &[22, 26, 181, 46], 81),
            (
                CanId::Extended(109780287),
                &[159, 0, 90, 247, 175, 186, 147, 68],
                137,
            ),
            (CanId::Standard(290), &[183, 152, 152, 65, 97, 68], 97),
            (CanId::Standard(1772), &[], 50),
            (CanId::Extended(140043020), &[104, 240, 35, 178], 101),
            (CanId::Standard(287), &[165, 1, 200, 47, 109, 122, 248], 111),
            (CanId::Standard(878), &[56, 116], 65),
        ];
        for (id, data, bits) in cases {
            assert_eq!(
                frame_bits(&CanFrame::new(id, data).unwrap()),
                bits,
                "{id:?} {data:?}"
            );
        }
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
