//! Unitree's low-level interface: the messages a Unitree robot's board exchanges with the user's
//! computer over DDS (`rt/lowcmd`, `rt/lowstate`), as the official SDK's IDL defines them, and the
//! CRC each one carries. `hg` is the family of the G1 and H1-2.
//!
//! The CRC is computed over the message laid out as the SDK's C structs are (each field at its
//! natural alignment, little-endian), read as 32-bit little-endian words, every word but the last
//! (the CRC itself): CRC-32 with polynomial 0x04C11DB7, initial value 0xFFFFFFFF, each word fed
//! most significant bit first, no reflection and no final XOR.

pub mod board;
pub mod hg;
pub mod host;
pub mod lockstep;
pub mod wire;

/// Unitree's CRC-32: feeding each 32-bit word most significant bit first into a register that
/// starts at all ones, shifting before the polynomial is applied, is CRC-32/MPEG-2 (polynomial
/// 0x04C11DB7, no reflection, no final XOR) over the words' big-endian bytes. Sliced 16 bytes at
/// a time: four CRCs of a 1 kB message every 2 ms link cycle were 6 % of a G1 run's CPU.
const CRC: crc::Crc<u32, crc::Table<16>> = crc::Crc::<u32, crc::Table<16>>::new(&crc::CRC_32_MPEG_2);

/// Unitree's CRC-32 of `words`.
pub fn crc32(words: impl IntoIterator<Item = u32>) -> u32 {
    let mut digest = CRC.digest();
    for word in words {
        digest.update(&word.to_be_bytes());
    }
    digest.finalize()
}

/// The most bytes a packed message has (the largest of the family).
const MAX_PACKED: usize = hg::LowState::PACKED_LEN;

/// Unitree's CRC of a packed message: its little-endian words, the last (the CRC) left out.
/// The words are turned big-endian into one buffer and fed at once (no allocation).
pub fn crc_of_packed(packed: &[u8]) -> u32 {
    let words = (packed.len() / 4).saturating_sub(1);
    let mut be = [0u8; MAX_PACKED];
    let mut fed = 0;
    for (chunk, out) in packed.chunks_exact(4).take(words).zip(be.chunks_exact_mut(4)) {
        out.copy_from_slice(&[chunk[3], chunk[2], chunk[1], chunk[0]]);
        fed += 4;
    }
    if fed < words * 4 {
        // Longer than any message of the family: fed word by word.
        return crc32(
            packed
                .chunks_exact(4)
                .take(words)
                .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]])),
        );
    }
    CRC.checksum(&be[..fed])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unitree's description, bit by bit: the register shifts, the polynomial goes in when the bit
    /// shifted out was set, and again when the data bit is.
    fn bitwise(words: &[u32]) -> u32 {
        let mut crc = 0xFFFF_FFFFu32;
        for word in words {
            for bit in (0..32).rev() {
                let top = crc & 0x8000_0000 != 0;
                crc <<= 1;
                if top {
                    crc ^= 0x04C1_1DB7;
                }
                if word >> bit & 1 == 1 {
                    crc ^= 0x04C1_1DB7;
                }
            }
        }
        crc
    }

    #[test]
    fn the_table_driven_crc_is_unitrees_bit_by_bit() {
        let mut x = 0x1234_5678u32;
        let words: Vec<u32> = (0..64)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                x
            })
            .collect();
        for n in [0, 1, 2, 7, 64] {
            assert_eq!(
                crc32(words[..n].iter().copied()),
                bitwise(&words[..n]),
                "{n} words"
            );
        }
    }

    #[test]
    fn the_crc_of_nothing_is_its_initial_value_and_one_bit_changes_it() {
        assert_eq!(crc32([]), 0xFFFF_FFFF);
        assert_ne!(crc32([0]), crc32([1]));
        // The last word of a packed message is its CRC and is not covered.
        assert_eq!(crc_of_packed(&[1, 0, 0, 0, 9, 9, 9, 9]), crc32([1]));
    }

    #[test]
    fn a_packed_message_of_any_length_gets_unitrees_bit_by_bit_crc() {
        let bytes: Vec<u8> = (0..2 * MAX_PACKED as u32)
            .map(|k| (k.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect();
        for n in [0, 4, 8, 9, 1004, MAX_PACKED + 8, 2 * MAX_PACKED] {
            let words: Vec<u32> = bytes[..n]
                .chunks_exact(4)
                .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]]))
                .collect();
            let covered = &words[..words.len().saturating_sub(1)];
            assert_eq!(crc_of_packed(&bytes[..n]), bitwise(covered), "{n} bytes");
        }
    }
}
