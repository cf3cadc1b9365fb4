//! Dynamixel Protocol 2.0 packet codec, shared by the host driver and the emulated servos.
//!
//! `FF FF FD 00 | ID | LEN_L LEN_H | INST | [ERR] | params | CRC_L CRC_H`, where LEN counts INST,
//! ERR (status packets only), the *stuffed* parameters and the CRC. The CRC-16 (polynomial 0x8005,
//! init 0, not reflected) covers everything from the header to the last stuffed parameter byte.
//! Stuffing inserts `FD` after every `FF FF FD` inside INST..params, so a header never appears
//! inside a packet. Encoding and decoding work in caller-owned buffers and never allocate.

/// The four header bytes.
pub const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];
/// Broadcast ID.
pub const BROADCAST_ID: u8 = 0xFE;
/// Instruction code of status packets.
pub const STATUS: u8 = 0x55;
/// Header + ID + LEN.
const PREFIX: usize = 7;

/// Instruction codes.
pub mod inst {
    /// Ping.
    pub const PING: u8 = 0x01;
    /// Read.
    pub const READ: u8 = 0x02;
    /// Write.
    pub const WRITE: u8 = 0x03;
    /// Registered write.
    pub const REG_WRITE: u8 = 0x04;
    /// Action (execute registered writes).
    pub const ACTION: u8 = 0x05;
    /// Factory reset.
    pub const FACTORY_RESET: u8 = 0x06;
    /// Reboot.
    pub const REBOOT: u8 = 0x08;
    /// Clear.
    pub const CLEAR: u8 = 0x10;
    /// Sync read.
    pub const SYNC_READ: u8 = 0x82;
    /// Sync write.
    pub const SYNC_WRITE: u8 = 0x83;
    /// Bulk read.
    pub const BULK_READ: u8 = 0x92;
    /// Bulk write.
    pub const BULK_WRITE: u8 = 0x93;
    /// Fast sync read: the listed servos answer in one status packet (ID 0xFE).
    pub const FAST_SYNC_READ: u8 = 0x8A;
    /// Fast bulk read: one status packet for the listed servos' own addresses and lengths.
    pub const FAST_BULK_READ: u8 = 0x9A;
}

/// The fixed part of a fast read's status packet: header, ID 0xFE, LEN, INST 0x55.
pub const FAST_STATUS_PREFIX: usize = 8;

/// Bytes each servo adds to a fast read's status packet besides its data: error, ID, CRC.
pub const FAST_SEGMENT_OVERHEAD: usize = 4;

/// Why bytes are not a packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PacketError {
    /// The CRC does not match.
    #[error("CRC mismatch: packet says {received:#06x}, bytes give {computed:#06x}")]
    Crc {
        /// CRC in the packet.
        received: u16,
        /// CRC of the bytes.
        computed: u16,
    },
    /// LEN is below the minimum for the packet kind.
    #[error("length field {0} is too small")]
    LengthTooSmall(u16),
    /// The packet does not fit the buffer.
    #[error("packet of {needed} bytes does not fit a {capacity}-byte buffer")]
    TooLarge {
        /// Bytes needed.
        needed: usize,
        /// Buffer size.
        capacity: usize,
    },
}

/// Dynamixel Protocol 2.0's CRC: polynomial 0x8005, initial 0, neither reflected nor inverted
/// (the catalogue's CRC-16/UMTS), sixteen tables for a byte-sliced update.
const DXL_CRC: crc::Crc<u16, crc::Table<16>> = crc::Crc::<u16, crc::Table<16>>::new(&crc::CRC_16_UMTS);

/// CRC-16 of Dynamixel Protocol 2.0, continued from `crc` over `data` (neither reflected nor
/// inverted, so a running value is the register itself).
pub fn crc16(crc: u16, data: &[u8]) -> u16 {
    let mut digest = DXL_CRC.digest_with_initial(crc);
    digest.update(data);
    digest.finalize()
}

/// Writes `body` (INST, ERR, params, unstuffed) stuffed into `out`; returns bytes written.
fn stuff_into(body_parts: &[&[u8]], out: &mut [u8]) -> Result<usize, PacketError> {
    let mut n = 0;
    let mut run = 0u8; // how many of FF FF FD have just been written
    for &b in body_parts.iter().flat_map(|p| p.iter()) {
        let slot = out.get_mut(n).ok_or(PacketError::TooLarge {
            needed: n + 1,
            capacity: n,
        })?;
        *slot = b;
        n += 1;
        run = match (run, b) {
            (0 | 1, 0xFF) => run + 1,
            (2, 0xFF) => 2,
            (2, 0xFD) => 3,
            _ => 0,
        };
        if run == 3 {
            let slot = out.get_mut(n).ok_or(PacketError::TooLarge {
                needed: n + 1,
                capacity: n,
            })?;
            *slot = 0xFD;
            n += 1;
            run = 0;
        }
    }
    Ok(n)
}

fn encode(id: u8, parts: &[&[u8]], out: &mut [u8]) -> Result<usize, PacketError> {
    let capacity = out.len();
    let too_large = |needed| PacketError::TooLarge { needed, capacity };
    if capacity < PREFIX + 3 {
        return Err(too_large(PREFIX + 3));
    }
    out[..4].copy_from_slice(&HEADER);
    out[4] = id;
    let body = stuff_into(parts, &mut out[PREFIX..capacity - 2]).map_err(|_| too_large(capacity + 1))?;
    let len = u16::try_from(body + 2).map_err(|_| too_large(PREFIX + body + 2))?;
    out[5..7].copy_from_slice(&len.to_le_bytes());
    let end = PREFIX + body;
    let crc = crc16(0, &out[..end]);
    out[end..end + 2].copy_from_slice(&crc.to_le_bytes());
    Ok(end + 2)
}

/// Encodes an instruction packet into `out`; returns its length.
pub fn encode_instruction(
    id: u8,
    instruction: u8,
    params: &[u8],
    out: &mut [u8],
) -> Result<usize, PacketError> {
    encode(id, &[&[instruction], params], out)
}

/// Encodes a status packet into `out`; returns its length.
pub fn encode_status(id: u8, error: u8, params: &[u8], out: &mut [u8]) -> Result<usize, PacketError> {
    encode(id, &[&[STATUS, error], params], out)
}

/// A decoded packet; `params` are unstuffed and borrowed from the caller's scratch buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Packet<'a> {
    /// Device ID.
    pub id: u8,
    /// Instruction code (0x55 for status).
    pub instruction: u8,
    /// Error byte of a status packet.
    pub error: Option<u8>,
    /// Parameters, unstuffed.
    pub params: &'a [u8],
}

/// What [`decode`] found at the front of a byte stream.
#[derive(Debug, PartialEq, Eq)]
pub enum Decoded<'a> {
    /// A packet, and how many input bytes it (and any junk before it) used.
    Packet(Packet<'a>, usize),
    /// Not enough bytes yet; `skip` leading bytes are junk and can be dropped now.
    Incomplete {
        /// Junk bytes before a possible header.
        skip: usize,
    },
    /// A broken packet (with the ID its header names, where it got that far): drop `skip` bytes
    /// and try again.
    Invalid(PacketError, Option<u8>, usize),
}

/// Finds and decodes the first packet in `input`, unstuffing its body into `scratch`.
pub fn decode<'a>(input: &[u8], scratch: &'a mut [u8]) -> Decoded<'a> {
    let Some(start) = input.windows(4).position(|w| w == HEADER) else {
        // Keep a possible partial header at the end.
        let keep = (1..=3)
            .rev()
            .find(|&k| input.len() >= k && input[input.len() - k..] == HEADER[..k])
            .unwrap_or(0);
        return Decoded::Incomplete {
            skip: input.len() - keep,
        };
    };
    let rest = &input[start..];
    if rest.len() < PREFIX {
        return Decoded::Incomplete { skip: start };
    }
    let id = rest[4];
    let len = u16::from_le_bytes([rest[5], rest[6]]);
    if len < 3 {
        return Decoded::Invalid(PacketError::LengthTooSmall(len), Some(id), start + 4);
    }
    let total = PREFIX + usize::from(len);
    if rest.len() < total {
        return Decoded::Incomplete { skip: start };
    }
    let received = u16::from_le_bytes([rest[total - 2], rest[total - 1]]);
    let computed = crc16(0, &rest[..total - 2]);
    if received != computed {
        return Decoded::Invalid(PacketError::Crc { received, computed }, Some(id), start + 4);
    }
    // Unstuff INST..params: drop the FD that follows every FF FF FD.
    let body = &rest[PREFIX..total - 2];
    let mut n = 0;
    let mut i = 0;
    while i < body.len() {
        if n >= scratch.len() {
            return Decoded::Invalid(
                PacketError::TooLarge {
                    needed: body.len(),
                    capacity: scratch.len(),
                },
                Some(id),
                start + total,
            );
        }
        scratch[n] = body[i];
        n += 1;
        if n >= 3 && scratch[n - 3..n] == [0xFF, 0xFF, 0xFD] && body.get(i + 1) == Some(&0xFD) {
            i += 1;
        }
        i += 1;
    }
    let unstuffed = &scratch[..n];
    let instruction = unstuffed[0];
    let (error, params) = if instruction == STATUS {
        match unstuffed.get(1) {
            Some(&e) => (Some(e), &unstuffed[2..]),
            None => return Decoded::Invalid(PacketError::LengthTooSmall(len), Some(id), start + total),
        }
    } else {
        (None, &unstuffed[1..])
    };
    Decoded::Packet(
        Packet {
            id,
            instruction,
            error,
            params,
        },
        start + total,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_vectors_encode_bit_exactly() {
        let mut buf = [0u8; 32];
        // Ping ID 1 (e-Manual Protocol 2.0): FF FF FD 00 01 03 00 01 19 4E.
        let n = encode_instruction(1, inst::PING, &[], &mut buf).unwrap();
        assert_eq!(
            &buf[..n],
            &[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E]
        );
        // Status OK, no parameters: FF FF FD 00 01 04 00 55 00 A1 0C.
        let n = encode_status(1, 0, &[], &mut buf).unwrap();
        assert_eq!(
            &buf[..n],
            &[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x04, 0x00, 0x55, 0x00, 0xA1, 0x0C]
        );
        assert_eq!(
            crc16(0, &[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01]),
            0x4E19
        );
        // Continued over a packet in pieces (a reply read as it arrives), the same.
        assert_eq!(
            crc16(crc16(0, &[0xFF, 0xFF, 0xFD]), &[0x00, 0x01, 0x03, 0x00, 0x01]),
            0x4E19
        );
    }

    #[test]
    fn manual_vectors_decode() {
        let mut scratch = [0u8; 16];
        let ping = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E];
        let Decoded::Packet(p, used) = decode(&ping, &mut scratch) else {
            panic!()
        };
        assert_eq!(
            (p.id, p.instruction, p.error, p.params, used),
            (1, inst::PING, None, &[][..], 10)
        );
        let status = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x04, 0x00, 0x55, 0x00, 0xA1, 0x0C];
        let Decoded::Packet(p, _) = decode(&status, &mut scratch) else {
            panic!()
        };
        assert_eq!((p.instruction, p.error), (STATUS, Some(0)));
    }

    #[test]
    fn stuffing_round_trips_and_counts_in_len() {
        let mut buf = [0u8; 64];
        let mut scratch = [0u8; 64];
        let params = [0xFF, 0xFF, 0xFD, 0x01, 0xFF, 0xFF, 0xFD];
        let n = encode_instruction(7, inst::WRITE, &params, &mut buf).unwrap();
        // Two FD bytes are inserted; LEN counts INST + 9 stuffed params + CRC = 12.
        assert_eq!(u16::from_le_bytes([buf[5], buf[6]]), 12);
        assert_eq!(
            &buf[8..18],
            &[0xFF, 0xFF, 0xFD, 0xFD, 0x01, 0xFF, 0xFF, 0xFD, 0xFD, buf[17]]
        );
        let Decoded::Packet(p, used) = decode(&buf[..n], &mut scratch) else {
            panic!()
        };
        assert_eq!((p.params, used), (&params[..], n));
    }

    #[test]
    fn junk_truncation_and_bad_crc_are_reported_not_fatal() {
        let mut buf = [0u8; 32];
        let mut scratch = [0u8; 32];
        let n = encode_instruction(3, inst::READ, &[132, 0, 4, 0], &mut buf).unwrap();
        let mut stream = vec![0x00, 0x13, 0xFF];
        stream.extend_from_slice(&buf[..n]);
        let Decoded::Packet(p, used) = decode(&stream, &mut scratch) else {
            panic!()
        };
        assert_eq!((p.id, used), (3, n + 3));
        assert_eq!(
            decode(&stream[..n], &mut scratch),
            Decoded::Incomplete { skip: 3 }
        );
        let mut bad = buf;
        bad[n - 1] ^= 0x01;
        assert!(matches!(
            decode(&bad[..n], &mut scratch),
            Decoded::Invalid(PacketError::Crc { .. }, Some(3), 4)
        ));
        let short_len = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x02, 0x00, 0x01, 0x00];
        assert!(matches!(
            decode(&short_len, &mut scratch),
            Decoded::Invalid(PacketError::LengthTooSmall(2), Some(1), 4)
        ));
        assert!(encode_instruction(1, inst::WRITE, &[0; 40], &mut buf).is_err());
    }

    #[test]
    fn random_streams_never_panic() {
        let mut rng = crate::time::SimRng::new(11);
        let mut scratch = [0u8; 64];
        for _ in 0..20_000 {
            let n = (rng.next_u64() % 40) as usize;
            let mut bytes: Vec<u8> = (0..n)
                .map(|_| [0xFF, 0xFD, 0x00, 0x01, 0x55, rng.next_u64() as u8][(rng.next_u64() % 6) as usize])
                .collect();
            if rng.chance(0.3) {
                bytes.splice(0..0, HEADER);
            }
            let mut input = &bytes[..];
            while !input.is_empty() {
                let used = match decode(input, &mut scratch) {
                    Decoded::Packet(_, used) | Decoded::Invalid(_, _, used) => used,
                    Decoded::Incomplete { .. } => break,
                };
                input = &input[used.clamp(1, input.len())..];
            }
        }
    }
}
