//! The STS series control table: addresses, factory values, baud rates, units.
//!
//! EPROM below address 40 (configuration; kept over power cycles only while Lock, 55, is 0), SRAM
//! from 40. Multi-byte values little-endian (STS; SCS servos are big-endian).

/// Addresses.
pub mod addr {
    /// Firmware major version.
    pub const FIRMWARE_MAJOR: u8 = 0;
    /// Firmware minor version.
    pub const FIRMWARE_MINOR: u8 = 1;
    /// Model number (2 bytes).
    pub const MODEL: u8 = 3;
    /// ID.
    pub const ID: u8 = 5;
    /// Baud rate index (see [`super::baud_of_index`]).
    pub const BAUD: u8 = 6;
    /// Return delay, 2 µs units.
    pub const RETURN_DELAY: u8 = 7;
    /// Response level: 0 answers only PING and READ, 1 answers every instruction to its ID.
    pub const RESPONSE_LEVEL: u8 = 8;
    /// Minimum angle limit, ticks (2 bytes).
    pub const MIN_ANGLE: u8 = 9;
    /// Maximum angle limit, ticks (2 bytes).
    pub const MAX_ANGLE: u8 = 11;
    /// Temperature limit, °C.
    pub const MAX_TEMPERATURE: u8 = 13;
    /// Maximum input voltage, 0.1 V.
    pub const MAX_VOLTAGE: u8 = 14;
    /// Minimum input voltage, 0.1 V.
    pub const MIN_VOLTAGE: u8 = 15;
    /// Maximum torque, 0.1 % (2 bytes): Torque Limit's value at power-up.
    pub const MAX_TORQUE: u8 = 16;
    /// Unloading condition: error bits that switch the output off.
    pub const UNLOADING: u8 = 19;
    /// Position loop P coefficient.
    pub const P_GAIN: u8 = 21;
    /// Position loop D coefficient.
    pub const D_GAIN: u8 = 22;
    /// Position loop I coefficient.
    pub const I_GAIN: u8 = 23;
    /// Homing offset, ticks (2 bytes, sign at bit 11): Present Position = encoder − offset.
    pub const HOMING_OFFSET: u8 = 31;
    /// Operating mode: 0 position, 1 wheel (speed), 2 PWM, 3 step.
    pub const MODE: u8 = 33;
    /// Output while overloaded, %.
    pub const PROTECTIVE_TORQUE: u8 = 34;
    /// Time over the overload threshold before protection, 10 ms units.
    pub const PROTECTION_TIME: u8 = 35;
    /// Overload threshold, %.
    pub const OVERLOAD_TORQUE: u8 = 36;
    /// Torque enable: 0 off, 1 on, 128 take the present position as the middle (2048).
    pub const TORQUE_ENABLE: u8 = 40;
    /// Acceleration, 100 step/s² units (0: none).
    pub const ACCELERATION: u8 = 41;
    /// Goal position, ticks (2 bytes, sign at bit 15).
    pub const GOAL_POSITION: u8 = 42;
    /// Goal time, ms (2 bytes).
    pub const GOAL_TIME: u8 = 44;
    /// Goal speed, step/s (2 bytes; 0: full speed).
    pub const GOAL_SPEED: u8 = 46;
    /// Torque limit, 0.1 % (2 bytes).
    pub const TORQUE_LIMIT: u8 = 48;
    /// EPROM lock: 1 locked (writes are not kept over a power cycle), 0 unlocked.
    pub const LOCK: u8 = 55;
    /// Present position, ticks (2 bytes).
    pub const PRESENT_POSITION: u8 = 56;
    /// Present speed, step/s (2 bytes, sign at bit 15).
    pub const PRESENT_SPEED: u8 = 58;
    /// Present load, 0.1 % of full output (2 bytes, sign at bit 10).
    pub const PRESENT_LOAD: u8 = 60;
    /// Present voltage, 0.1 V.
    pub const PRESENT_VOLTAGE: u8 = 62;
    /// Present temperature, °C.
    pub const PRESENT_TEMPERATURE: u8 = 63;
    /// Status: the error bits in force.
    pub const STATUS: u8 = 65;
    /// Moving: 1 while the shaft turns.
    pub const MOVING: u8 = 66;
    /// Present current, 6.5 mA units (2 bytes).
    pub const PRESENT_CURRENT: u8 = 69;
}

/// Bytes of the table.
pub const TABLE_LEN: usize = 71;

/// First SRAM address: below it is EPROM.
pub const SRAM_START: u8 = addr::TORQUE_ENABLE;

/// Encoder ticks per turn.
pub const TICKS_PER_TURN: i32 = 4096;

/// Present current per unit, A.
pub const CURRENT_UNIT_A: f64 = 0.0065;

/// The state block a host reads each cycle: Present Position (56) to Present Current's end (70).
pub const STATE_START: u8 = addr::PRESENT_POSITION;
/// Length of the state block.
pub const STATE_LEN: u8 = 15;

/// The baud rate of each index of address 6.
pub const BAUDS: [u32; 8] = [
    1_000_000, 500_000, 250_000, 128_000, 115_200, 76_800, 57_600, 38_400,
];

/// The baud rate of an index.
pub fn baud_of_index(index: u8) -> Option<u32> {
    BAUDS.get(usize::from(index)).copied()
}

/// The index of a baud rate, if the servos have it.
pub fn index_of_baud(baud: u32) -> Option<u8> {
    BAUDS.iter().position(|&b| b == baud).map(|i| i as u8)
}

/// Radians per encoder tick.
pub fn rad_per_tick() -> f64 {
    std::f64::consts::TAU / f64::from(TICKS_PER_TURN)
}

/// The emulated position loop's law (a model of the firmware, not a vendor figure): duty per
/// tick of error per unit of P, and per tick/s of speed per unit of D. The driver maps a policy's
/// stiffness and damping onto P and D with the same constants.
pub const P_DUTY_PER_TICK: f64 = 5e-4;
/// See [`P_DUTY_PER_TICK`].
pub const D_DUTY_PER_TICK_PER_S: f64 = 2e-5;
