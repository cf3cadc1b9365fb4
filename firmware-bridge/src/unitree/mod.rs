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
/// 0x04C11DB7, no reflection, no final XOR) over the words' big-endian bytes.
const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_MPEG_2);

/// Unitree's CRC-32 of `words`.
pub fn crc32(words: impl IntoIterator<Item = u32>) -> u32 {
    let mut digest = CRC.digest();
    for word in words {
        digest.update(&word.to_be_bytes());
    }
    digest.finalize()
}

/// Unitree's CRC of a packed message: its little-endian words, the last (the CRC) left out.
pub fn crc_of_packed(packed: &[u8]) -> u32 {
    let words = packed.len() / 4;
    crc32(
        packed
            .chunks_exact(4)
            .take(words.saturating_sub(1))
            .map(|w| u32::from_le_bytes([w[0], w[1], w[2], w[3]])),
    )
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
}
