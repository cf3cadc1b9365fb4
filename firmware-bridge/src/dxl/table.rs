//! The X-series control table: addresses, sizes, access rules and value ranges (e-Manual,
//! XM430-W350 / XL430-W250, firmware 4x).

/// Bytes of control table the emulator keeps (through Indirect Data 28).
pub const TABLE_LEN: usize = 252;
/// First RAM address; everything below is EEPROM.
pub const RAM_START: u16 = 64;

/// Control table addresses.
#[allow(missing_docs, reason = "the names are the manual's field names")]
pub mod addr {
    pub const MODEL_NUMBER: u16 = 0;
    pub const MODEL_INFORMATION: u16 = 2;
    pub const FIRMWARE_VERSION: u16 = 6;
    pub const ID: u16 = 7;
    pub const BAUD_RATE: u16 = 8;
    pub const RETURN_DELAY_TIME: u16 = 9;
    pub const DRIVE_MODE: u16 = 10;
    pub const OPERATING_MODE: u16 = 11;
    pub const SECONDARY_ID: u16 = 12;
    pub const PROTOCOL_TYPE: u16 = 13;
    pub const HOMING_OFFSET: u16 = 20;
    pub const MOVING_THRESHOLD: u16 = 24;
    pub const TEMPERATURE_LIMIT: u16 = 31;
    pub const MAX_VOLTAGE_LIMIT: u16 = 32;
    pub const MIN_VOLTAGE_LIMIT: u16 = 34;
    pub const PWM_LIMIT: u16 = 36;
    pub const CURRENT_LIMIT: u16 = 38;
    pub const VELOCITY_LIMIT: u16 = 44;
    pub const MAX_POSITION_LIMIT: u16 = 48;
    pub const MIN_POSITION_LIMIT: u16 = 52;
    pub const SHUTDOWN: u16 = 63;
    pub const TORQUE_ENABLE: u16 = 64;
    pub const LED: u16 = 65;
    pub const STATUS_RETURN_LEVEL: u16 = 68;
    pub const REGISTERED_INSTRUCTION: u16 = 69;
    pub const HARDWARE_ERROR_STATUS: u16 = 70;
    pub const VELOCITY_I_GAIN: u16 = 76;
    pub const VELOCITY_P_GAIN: u16 = 78;
    pub const POSITION_D_GAIN: u16 = 80;
    pub const POSITION_I_GAIN: u16 = 82;
    pub const POSITION_P_GAIN: u16 = 84;
    pub const FEEDFORWARD_2ND_GAIN: u16 = 88;
    pub const FEEDFORWARD_1ST_GAIN: u16 = 90;
    pub const BUS_WATCHDOG: u16 = 98;
    pub const GOAL_PWM: u16 = 100;
    pub const GOAL_CURRENT: u16 = 102;
    pub const GOAL_VELOCITY: u16 = 104;
    pub const PROFILE_ACCELERATION: u16 = 108;
    pub const PROFILE_VELOCITY: u16 = 112;
    pub const GOAL_POSITION: u16 = 116;
    pub const REALTIME_TICK: u16 = 120;
    pub const MOVING: u16 = 122;
    pub const MOVING_STATUS: u16 = 123;
    pub const PRESENT_PWM: u16 = 124;
    pub const PRESENT_CURRENT: u16 = 126;
    pub const PRESENT_VELOCITY: u16 = 128;
    pub const PRESENT_POSITION: u16 = 132;
    pub const VELOCITY_TRAJECTORY: u16 = 136;
    pub const POSITION_TRAJECTORY: u16 = 140;
    pub const PRESENT_INPUT_VOLTAGE: u16 = 144;
    pub const PRESENT_TEMPERATURE: u16 = 146;
    pub const INDIRECT_ADDRESS_1: u16 = 168;
    pub const INDIRECT_DATA_1: u16 = 224;
}

/// Number of indirect address/data pairs in the first block.
pub const INDIRECT_SLOTS: u16 = 28;

/// Hardware Error Status bits (address 70).
pub mod hw {
    /// Input voltage outside the limits.
    pub const VOLTAGE: u8 = 1 << 0;
    /// Internal temperature above the limit.
    pub const OVERHEAT: u8 = 1 << 2;
    /// Motor encoder malfunction.
    pub const ENCODER: u8 = 1 << 3;
    /// Electrical shock or insufficient power.
    pub const ELECTRICAL_SHOCK: u8 = 1 << 4;
    /// Persistent load above the maximum output.
    pub const OVERLOAD: u8 = 1 << 5;
    /// Factory Shutdown value: overheat, electrical shock, overload.
    pub const DEFAULT_SHUTDOWN: u8 = OVERHEAT | ELECTRICAL_SHOCK | OVERLOAD;
}

/// Error numbers of the status packet (bits 0–6 of the error byte); bit 7 is the alert flag.
pub mod status {
    /// Result fail: the instruction could not be processed.
    pub const RESULT_FAIL: u8 = 0x01;
    /// Undefined instruction, or Action without Reg Write.
    pub const INSTRUCTION: u8 = 0x02;
    /// CRC of the packet does not match.
    pub const CRC: u8 = 0x03;
    /// Data out of the field's range.
    pub const DATA_RANGE: u8 = 0x04;
    /// Data shorter than the field.
    pub const DATA_LENGTH: u8 = 0x05;
    /// Data beyond a configured limit.
    pub const DATA_LIMIT: u8 = 0x06;
    /// Read-only field, or EEPROM written with torque on.
    pub const ACCESS: u8 = 0x07;
    /// Alert: Hardware Error Status is non-zero.
    pub const ALERT: u8 = 0x80;

    /// The manual's name of an error number.
    pub fn name(error: u8) -> &'static str {
        match error & 0x7F {
            0 => "ok",
            RESULT_FAIL => "result fail",
            INSTRUCTION => "instruction error",
            CRC => "CRC error",
            DATA_RANGE => "data range error",
            DATA_LENGTH => "data length error",
            DATA_LIMIT => "data limit error",
            ACCESS => "access error",
            _ => "unknown error",
        }
    }
}

/// Who may write a field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Read only.
    Read,
    /// Read and write (EEPROM fields only with torque off).
    ReadWrite,
}

/// One control table field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Field {
    /// Address of the first byte.
    pub addr: u16,
    /// Size in bytes (1, 2 or 4).
    pub size: u8,
    /// Access rule.
    pub access: Access,
    /// Whether the value is two's-complement signed.
    pub signed: bool,
    /// Smallest value the field accepts.
    pub min: i64,
    /// Largest value the field accepts.
    pub max: i64,
    /// Present only on models that sense current (XM).
    pub needs_current_sensing: bool,
}

const fn f(addr: u16, size: u8, access: Access, min: i64, max: i64) -> Field {
    Field {
        addr,
        size,
        access,
        signed: min < 0,
        min,
        max,
        needs_current_sensing: false,
    }
}

const fn xm_only(field: Field) -> Field {
    Field {
        needs_current_sensing: true,
        ..field
    }
}

use Access::{Read as R, ReadWrite as RW};

/// Every field, in address order.
pub const FIELDS: &[Field] = &[
    f(addr::MODEL_NUMBER, 2, R, 0, 65535),
    f(addr::MODEL_INFORMATION, 4, R, 0, u32::MAX as i64),
    f(addr::FIRMWARE_VERSION, 1, R, 0, 255),
    f(addr::ID, 1, RW, 0, 252),
    f(addr::BAUD_RATE, 1, RW, 0, 7),
    f(addr::RETURN_DELAY_TIME, 1, RW, 0, 254),
    f(addr::DRIVE_MODE, 1, RW, 0, 13),
    f(addr::OPERATING_MODE, 1, RW, 0, 16),
    f(addr::SECONDARY_ID, 1, RW, 0, 255),
    f(addr::PROTOCOL_TYPE, 1, RW, 1, 2),
    f(addr::HOMING_OFFSET, 4, RW, -1_044_479, 1_044_479),
    f(addr::MOVING_THRESHOLD, 4, RW, 0, 1023),
    f(addr::TEMPERATURE_LIMIT, 1, RW, 0, 100),
    f(addr::MAX_VOLTAGE_LIMIT, 2, RW, 60, 140),
    f(addr::MIN_VOLTAGE_LIMIT, 2, RW, 60, 140),
    f(addr::PWM_LIMIT, 2, RW, 0, 885),
    xm_only(f(addr::CURRENT_LIMIT, 2, RW, 0, 1193)),
    f(addr::VELOCITY_LIMIT, 4, RW, 0, 1023),
    f(addr::MAX_POSITION_LIMIT, 4, RW, 0, 4095),
    f(addr::MIN_POSITION_LIMIT, 4, RW, 0, 4095),
    f(addr::SHUTDOWN, 1, RW, 0, 255),
    f(addr::TORQUE_ENABLE, 1, RW, 0, 1),
    f(addr::LED, 1, RW, 0, 1),
    f(addr::STATUS_RETURN_LEVEL, 1, RW, 0, 2),
    f(addr::REGISTERED_INSTRUCTION, 1, R, 0, 1),
    f(addr::HARDWARE_ERROR_STATUS, 1, R, 0, 255),
    f(addr::VELOCITY_I_GAIN, 2, RW, 0, 16383),
    f(addr::VELOCITY_P_GAIN, 2, RW, 0, 16383),
    f(addr::POSITION_D_GAIN, 2, RW, 0, 16383),
    f(addr::POSITION_I_GAIN, 2, RW, 0, 16383),
    f(addr::POSITION_P_GAIN, 2, RW, 0, 16383),
    f(addr::FEEDFORWARD_2ND_GAIN, 2, RW, 0, 16383),
    f(addr::FEEDFORWARD_1ST_GAIN, 2, RW, 0, 16383),
    // Bus Watchdog is signed: -1 marks an expired watchdog.
    f(addr::BUS_WATCHDOG, 1, RW, -1, 127),
    f(addr::GOAL_PWM, 2, RW, -885, 885),
    xm_only(f(addr::GOAL_CURRENT, 2, RW, -1193, 1193)),
    f(addr::GOAL_VELOCITY, 4, RW, -1023, 1023),
    f(addr::PROFILE_ACCELERATION, 4, RW, 0, 32767),
    f(addr::PROFILE_VELOCITY, 4, RW, 0, 32767),
    f(addr::GOAL_POSITION, 4, RW, -1_048_575, 1_048_575),
    f(addr::REALTIME_TICK, 2, R, 0, 32767),
    f(addr::MOVING, 1, R, 0, 1),
    f(addr::MOVING_STATUS, 1, R, 0, 255),
    f(addr::PRESENT_PWM, 2, R, -885, 885),
    f(addr::PRESENT_CURRENT, 2, R, -32768, 32767),
    f(addr::PRESENT_VELOCITY, 4, R, i32::MIN as i64, i32::MAX as i64),
    f(addr::PRESENT_POSITION, 4, R, i32::MIN as i64, i32::MAX as i64),
    f(addr::VELOCITY_TRAJECTORY, 4, R, i32::MIN as i64, i32::MAX as i64),
    f(addr::POSITION_TRAJECTORY, 4, R, i32::MIN as i64, i32::MAX as i64),
    f(addr::PRESENT_INPUT_VOLTAGE, 2, R, 0, 65535),
    f(addr::PRESENT_TEMPERATURE, 1, R, 0, 255),
];

/// Indirect Address `n` (1-based) is a 2-byte field naming any address from 64 up.
pub const fn indirect_address_field(slot: u16) -> Field {
    f(addr::INDIRECT_ADDRESS_1 + 2 * (slot - 1), 2, RW, 64, 661)
}

/// Indirect Data `n` (1-based): one byte standing for the byte at Indirect Address `n`.
pub const fn indirect_data_field(slot: u16) -> Field {
    f(addr::INDIRECT_DATA_1 + (slot - 1), 1, RW, 0, 255)
}

const NO_FIELD: u8 = u8::MAX;

/// For every address, the index of the field containing it in [`FIELDS`], or the indirect block.
const fn build_field_map() -> [u8; TABLE_LEN] {
    let mut map = [NO_FIELD; TABLE_LEN];
    let mut i = 0;
    while i < FIELDS.len() {
        let field = FIELDS[i];
        let mut b = 0;
        while b < field.size as usize {
            map[field.addr as usize + b] = i as u8;
            b += 1;
        }
        i += 1;
    }
    map
}

const FIELD_MAP: [u8; TABLE_LEN] = build_field_map();

/// The field holding byte `address` of the table, if any.
pub fn field_at(address: u16) -> Option<Field> {
    let a = usize::from(address);
    if a >= TABLE_LEN {
        return None;
    }
    let first_indirect = addr::INDIRECT_ADDRESS_1;
    if (first_indirect..addr::INDIRECT_DATA_1).contains(&address) {
        return Some(indirect_address_field((address - first_indirect) / 2 + 1));
    }
    if (addr::INDIRECT_DATA_1..addr::INDIRECT_DATA_1 + INDIRECT_SLOTS).contains(&address) {
        return Some(indirect_data_field(address - addr::INDIRECT_DATA_1 + 1));
    }
    match FIELD_MAP[a] {
        NO_FIELD => None,
        i => Some(FIELDS[usize::from(i)]),
    }
}

/// Reads a field's value from table bytes.
pub fn read_field(table: &[u8], field: Field) -> i64 {
    let at = usize::from(field.addr);
    match (field.size, field.signed) {
        (1, false) => i64::from(table[at]),
        (1, true) => i64::from(table[at] as i8),
        (2, false) => i64::from(u16::from_le_bytes([table[at], table[at + 1]])),
        (2, true) => i64::from(i16::from_le_bytes([table[at], table[at + 1]])),
        (_, false) => i64::from(u32::from_le_bytes(le4(table, at))),
        (_, true) => i64::from(i32::from_le_bytes(le4(table, at))),
    }
}

fn le4(table: &[u8], at: usize) -> [u8; 4] {
    [table[at], table[at + 1], table[at + 2], table[at + 3]]
}

/// Writes a field's value into table bytes (truncating to the field's size).
pub fn write_field(table: &mut [u8], field: Field, value: i64) {
    let at = usize::from(field.addr);
    let bytes = value.to_le_bytes();
    table[at..at + usize::from(field.size)].copy_from_slice(&bytes[..usize::from(field.size)]);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_do_not_overlap_and_fit_the_table() {
        let mut end = 0u16;
        for field in FIELDS {
            assert!(
                field.addr >= end,
                "field at {} overlaps the previous one",
                field.addr
            );
            end = field.addr + u16::from(field.size);
        }
        assert!(usize::from(end) <= usize::from(addr::INDIRECT_ADDRESS_1));
        assert_eq!(usize::from(addr::INDIRECT_DATA_1 + INDIRECT_SLOTS), TABLE_LEN);
    }

    #[test]
    fn field_lookup_covers_every_byte_of_a_field() {
        assert_eq!(field_at(118).unwrap().addr, addr::GOAL_POSITION);
        assert_eq!(field_at(171).unwrap(), indirect_address_field(2));
        assert_eq!(field_at(230).unwrap(), indirect_data_field(7));
        assert!(field_at(14).is_none() && field_at(300).is_none());
    }

    #[test]
    fn signed_fields_round_trip() {
        let mut t = [0u8; TABLE_LEN];
        let goal = field_at(addr::GOAL_CURRENT).unwrap();
        write_field(&mut t, goal, -300);
        assert_eq!(read_field(&t, goal), -300);
        let wd = field_at(addr::BUS_WATCHDOG).unwrap();
        write_field(&mut t, wd, -1);
        assert_eq!((t[98], read_field(&t, wd)), (0xFF, -1));
    }
}
