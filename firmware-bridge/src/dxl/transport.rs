//! How the host driver reaches a Dynamixel line: the protocol's framing ([`Dynamixel2`]) on the
//! protocol-agnostic ports of [`crate::half_duplex`]. [`SerialDxlPort::open`] sets the device up
//! through the `dynamixel2` crate and frames packets with this project's codec ([`packet`]):
//! dynamixel2 0.9.1's byte stuffing misses an `FF FF FD` that follows another `FF` (its pattern
//! matcher restarts from scratch), both ways — a status with a velocity of −1 before a position
//! ending in `FD` came out one byte long and was refused.

use super::packet::{self, Decoded};
pub use crate::half_duplex::{LinkError, StatusPacket, reply_budget};
use crate::half_duplex::{LockstepServoPort, SerialServoPort, ServoCodec, ServoTransport, StatusDecode};

/// Dynamixel Protocol 2.0 framing: header `FF FF FD 00`, byte stuffing, CRC-16.
#[derive(Debug, Clone, Copy)]
pub struct Dynamixel2;

impl ServoCodec for Dynamixel2 {
    const HEADER: &'static [u8] = &packet::HEADER;

    fn encode_instruction(id: u8, instruction: u8, params: &[u8], out: &mut [u8]) -> Option<usize> {
        packet::encode_instruction(id, instruction, params, out).ok()
    }

    fn decode_status(input: &[u8], scratch: &mut [u8]) -> StatusDecode {
        match packet::decode(input, scratch) {
            Decoded::Packet(p, used) if p.instruction == packet::STATUS => StatusDecode::Status {
                id: p.id,
                error: p.error.unwrap_or(0),
                // The codec leaves INST and ERR in front of the parameters.
                params: (2, 2 + p.params.len()),
                used,
            },
            Decoded::Packet(_, used) => StatusDecode::Invalid {
                error: LinkError::Malformed,
                used,
            },
            Decoded::Invalid(packet::PacketError::Crc { .. }, _, skip) => {
                // Skip the whole packet, as `dynamixel2` does, not just its header.
                let len = input
                    .get(skip + 1..skip + 3)
                    .map_or(0, |l| usize::from(u16::from_le_bytes([l[0], l[1]])));
                StatusDecode::Invalid {
                    error: LinkError::Crc,
                    used: (skip + 3 + len).min(input.len()),
                }
            }
            Decoded::Invalid(_, _, skip) => StatusDecode::Invalid {
                error: LinkError::Malformed,
                used: skip,
            },
            Decoded::Incomplete { skip } => StatusDecode::Incomplete { skip },
        }
    }
}

/// A half-duplex Dynamixel line as the host driver sees it.
pub trait DxlTransport: ServoTransport<Codec = Dynamixel2> {}

impl<T: ServoTransport<Codec = Dynamixel2>> DxlTransport for T {}

/// A serial device speaking Dynamixel 2.0.
pub type SerialDxlPort = SerialServoPort<Dynamixel2>;

/// The host's end of a Dynamixel line of a simulated world.
pub type LockstepDxlPort<W> = LockstepServoPort<W, Dynamixel2>;

impl SerialServoPort<Dynamixel2> {
    /// Opens `path` at `baud` (8N1, raw), set up by the `dynamixel2` crate.
    pub fn open(path: &str, baud: u32) -> std::io::Result<Self> {
        let bus = dynamixel2::Bus::open_with_buffers(path, baud, vec![0; 64], vec![0; 64])?;
        let port = bus.serial_port().try_clone()?;
        Ok(Self::from_port(port, baud))
    }
}
