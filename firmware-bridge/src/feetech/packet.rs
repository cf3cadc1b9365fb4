//! Feetech's serial protocol (SCS/STS): packets, checksum, sign-magnitude values.
//!
//! Instruction `FF FF ID LEN INSTR P… CHK`, status `FF FF ID LEN ERR P… CHK`; `LEN` is the
//! number of parameters plus 2; `CHK = ~(ID + LEN + INSTR/ERR + ΣP) & 0xFF`. No byte stuffing: a
//! packet's length is in its header. Signed values are sign-magnitude: bit 15 for position and
//! speed, bit 10 for load, bit 11 for the homing offset.

use crate::half_duplex::{LinkError, ServoCodec, StatusDecode};

/// Every packet starts with these.
pub const HEADER: [u8; 2] = [0xFF, 0xFF];
/// The ID every servo listens to (and none answers on).
pub const BROADCAST_ID: u8 = 0xFE;
/// Most parameters in one packet (`LEN` is one byte).
pub const MAX_PARAMS: usize = 253;

/// Instructions.
pub mod inst {
    /// Ping: the servo answers with an empty status.
    pub const PING: u8 = 0x01;
    /// Read `[address, length]`.
    pub const READ: u8 = 0x02;
    /// Write `[address, data…]`.
    pub const WRITE: u8 = 0x03;
    /// Write held until ACTION.
    pub const REG_WRITE: u8 = 0x04;
    /// Carry out held writes.
    pub const ACTION: u8 = 0x05;
    /// Restore factory settings.
    pub const RESET: u8 = 0x0A;
    /// Sync read to 0xFE `[address, length, id…]`: each listed servo answers in turn.
    pub const SYNC_READ: u8 = 0x82;
    /// Sync write to 0xFE `[address, length, (id, data…)…]`: no answer.
    pub const SYNC_WRITE: u8 = 0x83;
}

/// Bits of a status packet's error byte (and of the Status register, 65).
pub mod error {
    /// Input voltage out of the limits.
    pub const VOLTAGE: u8 = 1;
    /// Angle sensor fault.
    pub const ANGLE_SENSOR: u8 = 2;
    /// Overheat.
    pub const OVERHEAT: u8 = 4;
    /// Overcurrent.
    pub const OVERCURRENT: u8 = 8;
    /// Overload.
    pub const OVERLOAD: u8 = 32;
}

/// The checksum of the bytes from ID to the last parameter.
pub fn checksum(body: &[u8]) -> u8 {
    !body.iter().fold(0u8, |s, &b| s.wrapping_add(b))
}

/// Encodes a packet — `first` is the instruction, or the error byte of a status — into `out`;
/// its length, or `None` when the parameters are too many or `out` too short.
pub fn encode(id: u8, first: u8, params: &[u8], out: &mut [u8]) -> Option<usize> {
    let total = params.len() + 6;
    if params.len() > MAX_PARAMS || out.len() < total {
        return None;
    }
    out[..2].copy_from_slice(&HEADER);
    out[2] = id;
    out[3] = (params.len() + 2) as u8;
    out[4] = first;
    out[5..5 + params.len()].copy_from_slice(params);
    out[total - 1] = checksum(&out[2..total - 1]);
    Some(total)
}

/// What [`decode`] found at the front of a byte stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decoded {
    /// A packet: ID, instruction or error byte, its parameters at `input[params.0..params.1]`,
    /// and the bytes it (and junk before it) used.
    Packet {
        /// Device ID.
        id: u8,
        /// Instruction, or a status's error byte.
        first: u8,
        /// Where the parameters are in the input.
        params: (usize, usize),
        /// Input bytes used.
        used: usize,
    },
    /// Not enough bytes yet; `skip` leading bytes are junk.
    Incomplete {
        /// Junk bytes before a possible header.
        skip: usize,
    },
    /// A broken packet (its ID where it got that far): drop `skip` bytes and try again.
    Invalid {
        /// Checksum mismatch (else: malformed header).
        checksum: bool,
        /// The ID the header names.
        id: Option<u8>,
        /// Bytes to drop.
        skip: usize,
    },
}

/// The packet at the front of `input`.
pub fn decode(input: &[u8]) -> Decoded {
    let Some(start) = input.windows(2).position(|w| w == HEADER) else {
        let keep = usize::from(input.last() == Some(&0xFF));
        return Decoded::Incomplete {
            skip: input.len() - keep,
        };
    };
    let rest = &input[start..];
    if rest.len() < 4 {
        return Decoded::Incomplete { skip: start };
    }
    let (id, len) = (rest[2], usize::from(rest[3]));
    if id == 0xFF {
        // `FF FF FF`: the header may start one byte on.
        return Decoded::Invalid {
            checksum: false,
            id: None,
            skip: start + 1,
        };
    }
    if len < 2 {
        return Decoded::Invalid {
            checksum: false,
            id: Some(id),
            skip: start + 2,
        };
    }
    let total = 4 + len;
    if rest.len() < total {
        return Decoded::Incomplete { skip: start };
    }
    if checksum(&rest[2..total - 1]) != rest[total - 1] {
        return Decoded::Invalid {
            checksum: true,
            id: Some(id),
            skip: start + total,
        };
    }
    Decoded::Packet {
        id,
        first: rest[4],
        params: (start + 5, start + total - 1),
        used: start + total,
    }
}

/// `v` in sign-magnitude with its sign at bit `sign_bit` (the magnitude saturates).
pub fn to_sign_magnitude(v: i32, sign_bit: u32) -> u16 {
    let max = (1u32 << sign_bit) - 1;
    let magnitude = v.unsigned_abs().min(max);
    (magnitude | u32::from(v < 0) << sign_bit) as u16
}

/// A sign-magnitude value with its sign at bit `sign_bit`.
pub fn from_sign_magnitude(raw: u16, sign_bit: u32) -> i32 {
    let magnitude = i32::from(raw) & ((1 << sign_bit) - 1);
    if raw & (1 << sign_bit) != 0 {
        -magnitude
    } else {
        magnitude
    }
}

/// Feetech framing for the host ports of [`crate::half_duplex`].
#[derive(Debug, Clone, Copy)]
pub struct Feetech;

impl ServoCodec for Feetech {
    const HEADER: &'static [u8] = &HEADER;

    fn encode_instruction(id: u8, instruction: u8, params: &[u8], out: &mut [u8]) -> Option<usize> {
        encode(id, instruction, params, out)
    }

    fn decode_status(input: &[u8], scratch: &mut [u8]) -> StatusDecode {
        match decode(input) {
            Decoded::Packet {
                id,
                first,
                params: (from, to),
                used,
            } => {
                // A status's error byte keeps bit 7 clear (the vendor SDK refuses others) and
                // names a servo, not the broadcast ID.
                if first > 0x7F || id >= BROADCAST_ID || to - from > scratch.len() {
                    return StatusDecode::Invalid {
                        error: LinkError::Malformed,
                        used,
                    };
                }
                scratch[..to - from].copy_from_slice(&input[from..to]);
                StatusDecode::Status {
                    id,
                    error: first,
                    params: (0, to - from),
                    used,
                }
            }
            Decoded::Incomplete { skip } => StatusDecode::Incomplete { skip },
            Decoded::Invalid { checksum, skip, .. } => StatusDecode::Invalid {
                error: if checksum {
                    LinkError::Crc
                } else {
                    LinkError::Malformed
                },
                used: skip,
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packets_match_the_protocol_bytes() {
        let mut out = [0u8; 32];
        // Ping servo 1: FF FF 01 02 01 FB (~(1 + 2 + 1) = 0xFB).
        let n = encode(1, inst::PING, &[], &mut out).unwrap();
        assert_eq!(&out[..n], &[0xFF, 0xFF, 0x01, 0x02, 0x01, 0xFB]);
        // Read servo 1's present position (56, 2 bytes): FF FF 01 04 02 38 02 BE.
        let n = encode(1, inst::READ, &[56, 2], &mut out).unwrap();
        assert_eq!(&out[..n], &[0xFF, 0xFF, 0x01, 0x04, 0x02, 0x38, 0x02, 0xBE]);
        // Its answer, position 2048 (00 08), no error.
        let answer = [0xFF, 0xFF, 0x01, 0x04, 0x00, 0x00, 0x08, 0xF2];
        assert_eq!(checksum(&answer[2..7]), 0xF2);
        match decode(&answer) {
            Decoded::Packet {
                id,
                first,
                params,
                used,
            } => {
                assert_eq!(
                    (id, first, &answer[params.0..params.1], used),
                    (1, 0, &[0x00, 0x08][..], 8)
                );
            }
            other => panic!("{other:?}"),
        }
        // Junk before, a bad checksum, a split packet.
        let mut bad = answer;
        bad[7] ^= 1;
        assert!(matches!(
            decode(&bad),
            Decoded::Invalid {
                checksum: true,
                id: Some(1),
                skip: 8
            }
        ));
        assert_eq!(decode(&answer[..5]), Decoded::Incomplete { skip: 0 });
        let mut junk = vec![0x12, 0xFF];
        junk.extend_from_slice(&answer);
        assert!(matches!(
            decode(&junk),
            Decoded::Invalid {
                id: None,
                skip: 2,
                ..
            }
        ));
        assert!(matches!(decode(&junk[2..]), Decoded::Packet { used: 8, .. }));
    }

    #[test]
    fn sign_magnitude_puts_the_sign_where_the_table_says() {
        assert_eq!(to_sign_magnitude(-100, 15), 0x8064);
        assert_eq!(from_sign_magnitude(0x8064, 15), -100);
        // Load: sign at bit 10, magnitude saturating at 1023.
        assert_eq!(to_sign_magnitude(-2000, 10), 0x07FF);
        assert_eq!(from_sign_magnitude(0x0400 | 500, 10), -500);
        // Homing offset: bit 11.
        assert_eq!(from_sign_magnitude(to_sign_magnitude(-1500, 11), 11), -1500);
    }
}
