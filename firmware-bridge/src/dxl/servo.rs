//! Emulated X-series servo firmware: the servo side of Protocol 2.0 on the shared codec.
//!
//! One [`XSeriesServo`] owns its control table and answers instruction packets the way the
//! e-Manual specifies (error byte, Status Return Level, EEPROM lock while torque is on, Bus
//! Watchdog, hardware errors and the shutdown mask, reboot and factory reset). Every control
//! period it runs its own position/velocity/current loop, converts the PWM it commands into a
//! winding current through a DC motor model of the model's data, and applies the resulting torque
//! to a [`MotorPlant`]. Wire timing (who answers when) is the [`super::wire`] module's job.

use std::f64::consts::TAU;
use std::time::Duration;

use super::models::{self, DxlModel, PWM_FULL_SCALE};
use super::packet::{BROADCAST_ID, Packet, inst};
use super::table::{self, Access, Field, TABLE_LEN, addr, hw, status};
use crate::plant::MotorPlant;
use crate::time::SimInstant;

/// How an emulated servo is built into a machine.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoConfig {
    /// Factory ID (the manual's default is 1).
    pub id: u8,
    /// Supply voltage, V.
    pub supply_voltage: f64,
    /// Encoder reading when the plant is at angle 0 (2048: joint zero at the horn's centre).
    pub mount_offset_ticks: i32,
    /// Period of the servo's internal control loop.
    pub control_period: Duration,
    /// Time after a reboot before the servo answers again.
    pub boot_time: Duration,
    /// Ambient temperature, °C.
    pub ambient_temperature: f64,
    /// Thermal resistance winding → ambient, K/W.
    pub thermal_resistance: f64,
    /// Thermal capacity, J/K.
    pub thermal_capacity: f64,
    /// Return Delay Time after a factory reset, 2 µs units (the manual's default 250).
    pub factory_return_delay: u8,
    /// Baud Rate code after a factory reset (1 = 57600, the manual's default).
    pub factory_baud_code: u8,
}

impl ServoConfig {
    /// A servo with ID `id` at 12 V, control at 2 kHz, booting in 100 ms.
    pub fn new(id: u8) -> Self {
        Self {
            id,
            supply_voltage: 12.0,
            mount_offset_ticks: 2048,
            control_period: Duration::from_micros(500),
            boot_time: Duration::from_millis(100),
            ambient_temperature: 25.0,
            thermal_resistance: 4.0,
            thermal_capacity: 25.0,
            factory_return_delay: 250,
            factory_baud_code: 1,
        }
    }

    /// The same servo set up for a line at `baud`, answering after `return_delay`.
    ///
    /// # Panics
    /// When X-series servos do not support `baud`.
    pub fn on_line(mut self, baud: u32, return_delay: Duration) -> Self {
        self.factory_baud_code =
            super::wire::code_of_baud(baud).expect("a baud rate X-series servos support");
        self.factory_return_delay = (return_delay.as_micros() / 2).min(254) as u8;
        self
    }
}

pub use crate::half_duplex::ReplyFault;

/// A reply fault and how many more status packets it affects (`None`: until cleared).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct InjectedFault {
    /// What happens.
    pub fault: ReplyFault,
    /// Status packets still affected.
    pub remaining: Option<u32>,
}

/// Where a status packet goes in the order of answers on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplySlot {
    /// Right after the instruction.
    First,
    /// After the servos listed before it in a sync/bulk read (0-based position).
    InList(usize),
    /// After the servos with lower IDs, for a broadcast ping.
    ById,
    /// Its segment of a fast read's one status packet, at this place in the list.
    Fast(usize),
}

/// A status packet a servo wants to send, its parameters in the servo's reply buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reply {
    /// ID in the status packet.
    pub id: u8,
    /// Error byte.
    pub error: u8,
    /// Parameter bytes in [`XSeriesServo::reply_params`].
    pub len: usize,
    /// Order on the wire.
    pub slot: ReplySlot,
    /// Extra delay before it (injected faults).
    pub extra_delay: Duration,
    /// Whether to corrupt its CRC (injected fault).
    pub corrupt_crc: bool,
}

/// Counters of what a servo saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServoStats {
    /// Packets addressed to it (directly, by broadcast or in a sync/bulk list).
    pub packets: u64,
    /// Packets it answered with a non-zero error number.
    pub errors: u64,
    /// Control periods run.
    pub control_ticks: u64,
    /// Times the Bus Watchdog expired.
    pub watchdog_expiries: u64,
}

const REPLY_CAPACITY: usize = TABLE_LEN + 3;

/// One emulated X-series servo.
#[derive(Debug, Clone)]
pub struct XSeriesServo {
    model: DxlModel,
    config: ServoConfig,
    table: [u8; TABLE_LEN],
    registered: Option<(u16, usize, [u8; TABLE_LEN])>,
    reply: [u8; REPLY_CAPACITY],
    position_integral: f64,
    velocity_integral: f64,
    previous_error: f64,
    multi_turn_base: i64,
    /// Set at power-up and reboot: the next sample starts Present Position within one turn
    /// (0–4095), as the absolute single-turn encoder reads it; it counts turns from there.
    boot_turn_pending: bool,
    temperature: f64,
    overload_seconds: f64,
    /// Torque the motor applied in the last control period, N·m (servo side).
    applied_torque: f64,
    /// The torque that acted on the shaft, N·m, where a simulator applies its own servo model
    /// (see [`Self::sense_torque`]): what the current sensor reports instead of the emulated loop's.
    sensed_torque: Option<f64>,
    last_instruction_at: SimInstant,
    offline_until: Option<SimInstant>,
    vanished: bool,
    fault: Option<InjectedFault>,
    stats: ServoStats,
}

impl XSeriesServo {
    /// A servo of `model` fresh from the factory apart from its ID.
    pub fn new(model: &DxlModel, config: ServoConfig) -> Self {
        let mut servo = Self {
            model: model.clone(),
            temperature: config.ambient_temperature,
            config,
            table: [0; TABLE_LEN],
            registered: None,
            reply: [0; REPLY_CAPACITY],
            position_integral: 0.0,
            velocity_integral: 0.0,
            previous_error: 0.0,
            multi_turn_base: 0,
            boot_turn_pending: true,
            overload_seconds: 0.0,
            applied_torque: 0.0,
            sensed_torque: None,
            last_instruction_at: SimInstant::ZERO,
            offline_until: None,
            vanished: false,
            fault: None,
            stats: ServoStats::default(),
        };
        servo.factory_reset(0xFF);
        let id = servo.config.id;
        servo.table[usize::from(addr::ID)] = id;
        servo
    }

    /// The model it emulates.
    pub fn model(&self) -> &DxlModel {
        &self.model
    }

    /// Its current ID (address 7).
    pub fn id(&self) -> u8 {
        self.table[usize::from(addr::ID)]
    }

    /// Its Baud Rate code (address 8).
    pub fn baud_code(&self) -> u8 {
        self.table[usize::from(addr::BAUD_RATE)]
    }

    /// Return Delay Time (address 9).
    pub fn return_delay(&self) -> Duration {
        Duration::from_micros(2 * u64::from(self.table[usize::from(addr::RETURN_DELAY_TIME)]))
    }

    /// Reads a field by address (for tests and the mirror's telemetry).
    ///
    /// # Panics
    /// When `address` is not the start of a field.
    pub fn register(&self, address: u16) -> i64 {
        let field = table::field_at(address).expect("a control table field");
        assert_eq!(field.addr, address, "address {address} is inside a field");
        table::read_field(&self.table, field)
    }

    /// The most torque the servo gives with its present settings, N·m: the stall torque at its
    /// PWM Limit, and in current-based position control the torque of its Goal Current (within
    /// its Current Limit).
    pub fn torque_cap(&self) -> f64 {
        let m = &self.model;
        let by_pwm = self.reg(addr::PWM_LIMIT) as f64 / PWM_FULL_SCALE * m.stall_torque;
        if m.current_sensing && self.reg(addr::OPERATING_MODE) == 5 {
            let amps = (self.reg(addr::GOAL_CURRENT).abs()).min(self.reg(addr::CURRENT_LIMIT)) as f64
                * models::CURRENT_UNIT_A;
            by_pwm.min(amps * m.torque_constant())
        } else {
            by_pwm
        }
    }

    /// Torque the motor applied in its last control period, N·m (servo side, signed).
    pub fn applied_torque(&self) -> f64 {
        self.applied_torque
    }

    /// The torque that acted on the shaft, N·m (servo side), from a simulator whose own servo
    /// model drives the joint (a position actuator of the model, with this servo's gains): from
    /// then on the servo's current and load registers report it, and it heats by it, as its sensor
    /// would; the emulated loop still owns torque on/off, limits and faults.
    pub fn sense_torque(&mut self, torque: f64) {
        self.sensed_torque = Some(torque);
    }

    /// Whether torque is on.
    pub fn torque_enabled(&self) -> bool {
        self.table[usize::from(addr::TORQUE_ENABLE)] == 1
    }

    /// The stiffness (N·m/rad) and damping (N·m·s/rad) at the shaft that its position loop's P
    /// and D gains give, at stall and nominal supply (PWM P/128 per tick of error, D/16 per tick
    /// per control period; full PWM gives the stall torque): what a simulator's position actuator
    /// applies while it tracks [`Self::position_goal`].
    pub fn position_stiffness(&self) -> [f64; 2] {
        let per_tick = models::rad_per_tick();
        let torque_per_pwm = self.model.stall_torque / PWM_FULL_SCALE;
        let [p, d] = [addr::POSITION_P_GAIN, addr::POSITION_D_GAIN].map(|a| self.reg(a) as f64);
        [
            p / 128.0 * torque_per_pwm / per_tick,
            // The D term acts on the error's change over one control period.
            d / 16.0 * torque_per_pwm * self.config.control_period.as_secs_f64() / per_tick,
        ]
    }

    /// The shaft angle (rad, plant frame) Goal Position asks for, while torque is on in a
    /// position mode: what a simulator's position actuator should track instead of the torque.
    pub fn position_goal(&self) -> Option<f64> {
        if !self.torque_enabled() || !matches!(self.reg(addr::OPERATING_MODE), 3..=5) {
            return None;
        }
        let reverse = if self.table[usize::from(addr::DRIVE_MODE)] & 1 == 1 {
            -1.0
        } else {
            1.0
        };
        let ticks = self.reg(addr::GOAL_POSITION)
            - self.reg(addr::HOMING_OFFSET)
            - self.multi_turn_base
            - i64::from(self.config.mount_offset_ticks);
        Some(reverse * ticks as f64 * models::rad_per_tick())
    }

    /// Hardware Error Status (address 70).
    pub fn hardware_error(&self) -> u8 {
        self.table[usize::from(addr::HARDWARE_ERROR_STATUS)]
    }

    /// Winding temperature, °C.
    pub fn temperature(&self) -> f64 {
        self.temperature
    }

    /// Counters.
    pub fn stats(&self) -> ServoStats {
        self.stats
    }

    /// The parameters of the last [`Reply`].
    pub fn reply_params(&self, reply: &Reply) -> &[u8] {
        &self.reply[..reply.len]
    }

    /// Injects a reply fault (replacing any other).
    pub fn inject(&mut self, fault: ReplyFault, count: Option<u32>) {
        self.fault = Some(InjectedFault {
            fault,
            remaining: count,
        });
    }

    /// Clears injected reply faults.
    pub fn clear_faults(&mut self) {
        self.fault = None;
    }

    /// Raises hardware error bits as the firmware would on detecting them.
    pub fn raise_hardware_error(&mut self, bits: u8) {
        self.table[usize::from(addr::HARDWARE_ERROR_STATUS)] |= bits;
        self.apply_shutdown();
    }

    /// The servo loses power for good: no more answers, no torque.
    pub fn vanish(&mut self) {
        self.vanished = true;
        self.table[usize::from(addr::TORQUE_ENABLE)] = 0;
    }

    /// Whether the servo is powered and booted at `now`.
    pub fn is_online(&self, now: SimInstant) -> bool {
        !self.vanished && self.offline_until.is_none_or(|t| now >= t)
    }

    fn reg(&self, address: u16) -> i64 {
        table::read_field(&self.table, table::field_at(address).expect("known field"))
    }

    fn set_reg(&mut self, address: u16, value: i64) {
        let field = table::field_at(address).expect("known field");
        table::write_field(&mut self.table, field, value);
    }

    fn shutdown_active(&self) -> bool {
        self.hardware_error() & self.table[usize::from(addr::SHUTDOWN)] != 0
    }

    fn apply_shutdown(&mut self) {
        if self.shutdown_active() {
            self.table[usize::from(addr::TORQUE_ENABLE)] = 0;
        }
    }

    fn factory_reset(&mut self, kind: u8) {
        let id = self.id();
        let baud = self.baud_code();
        let m = self.model.clone();
        self.table = [0; TABLE_LEN];
        self.set_reg(addr::MODEL_NUMBER, i64::from(m.model_number));
        self.set_reg(addr::FIRMWARE_VERSION, i64::from(m.firmware_version));
        self.set_reg(addr::ID, 1);
        self.set_reg(addr::BAUD_RATE, i64::from(self.config.factory_baud_code));
        self.set_reg(
            addr::RETURN_DELAY_TIME,
            i64::from(self.config.factory_return_delay),
        );
        self.set_reg(addr::OPERATING_MODE, 3);
        self.set_reg(addr::PROTOCOL_TYPE, 2);
        self.set_reg(addr::MOVING_THRESHOLD, 10);
        self.set_reg(addr::TEMPERATURE_LIMIT, i64::from(m.temperature_limit));
        self.set_reg(addr::MAX_VOLTAGE_LIMIT, 140);
        self.set_reg(addr::MIN_VOLTAGE_LIMIT, 60);
        self.set_reg(addr::PWM_LIMIT, i64::from(m.pwm_limit));
        if m.current_sensing {
            self.set_reg(addr::CURRENT_LIMIT, i64::from(m.current_limit));
        }
        self.set_reg(addr::VELOCITY_LIMIT, i64::from(m.velocity_limit));
        self.set_reg(addr::MAX_POSITION_LIMIT, 4095);
        self.set_reg(addr::MIN_POSITION_LIMIT, 0);
        self.set_reg(addr::SHUTDOWN, i64::from(hw::DEFAULT_SHUTDOWN));
        match kind {
            0x01 => self.set_reg(addr::ID, i64::from(id)),
            0x02 => {
                self.set_reg(addr::ID, i64::from(id));
                self.set_reg(addr::BAUD_RATE, i64::from(baud));
            }
            _ => {}
        }
        self.reset_ram();
    }

    /// RAM as after power-on; EEPROM (below address 64) is kept.
    fn reset_ram(&mut self) {
        self.table[usize::from(table::RAM_START)..].fill(0);
        let m = &self.model;
        let [p, i, d] = m.position_gains;
        let [vp, vi] = m.velocity_gains;
        self.set_reg(addr::STATUS_RETURN_LEVEL, 2);
        self.set_reg(addr::POSITION_P_GAIN, i64::from(p));
        self.set_reg(addr::POSITION_I_GAIN, i64::from(i));
        self.set_reg(addr::POSITION_D_GAIN, i64::from(d));
        self.set_reg(addr::VELOCITY_P_GAIN, i64::from(vp));
        self.set_reg(addr::VELOCITY_I_GAIN, i64::from(vi));
        for slot in 1..=table::INDIRECT_SLOTS {
            // Factory indirect addresses point at the indirect data bytes themselves.
            self.set_reg(
                table::indirect_address_field(slot).addr,
                i64::from(addr::INDIRECT_DATA_1 + slot - 1),
            );
        }
        self.registered = None;
        self.position_integral = 0.0;
        self.velocity_integral = 0.0;
        self.multi_turn_base = 0;
    }

    // ---------------------------------------------------------------- instruction handling

    /// Executes an instruction packet that arrived complete at `now`. Returns the status packet
    /// the servo sends, if any; `None` also when the packet is not for this servo.
    pub fn handle(&mut self, packet: &Packet<'_>, now: SimInstant) -> Option<Reply> {
        if !self.is_online(now) {
            return None;
        }
        let id = self.id();
        let direct = packet.id == id;
        let broadcast = packet.id == BROADCAST_ID;
        if !direct && !broadcast {
            return None;
        }
        // A write that changes the Status Return Level is still answered per the old level.
        let level = self.table[usize::from(addr::STATUS_RETURN_LEVEL)];
        let (result, slot) = match (packet.instruction, broadcast) {
            (
                inst::SYNC_READ
                | inst::SYNC_WRITE
                | inst::BULK_READ
                | inst::BULK_WRITE
                | inst::FAST_SYNC_READ
                | inst::FAST_BULK_READ,
                true,
            ) => self.handle_group(packet)?,
            (inst::PING, _) => (
                Ok(self.ping_reply()),
                if broadcast {
                    ReplySlot::ById
                } else {
                    ReplySlot::First
                },
            ),
            _ => (self.handle_single(packet, now), ReplySlot::First),
        };
        self.stats.packets += 1;
        self.last_instruction_at = now;
        let (error, len) = match result {
            Ok(len) => (0, len),
            Err(e) => {
                self.stats.errors += 1;
                (e, 0)
            }
        };
        let reads = matches!(
            packet.instruction,
            inst::READ | inst::SYNC_READ | inst::BULK_READ | inst::FAST_SYNC_READ | inst::FAST_BULK_READ
        );
        let answers = match packet.instruction {
            inst::PING => true,
            _ if broadcast && !matches!(slot, ReplySlot::InList(_) | ReplySlot::Fast(_)) => false,
            _ if reads => level >= 1,
            _ => level >= 2,
        };
        if !answers {
            return None;
        }
        self.finish_reply(error, len, slot)
    }

    /// A status packet for an instruction whose CRC did not match (if it was addressed here).
    pub fn handle_crc_error(&mut self, packet_id: u8, now: SimInstant) -> Option<Reply> {
        if !self.is_online(now) || packet_id != self.id() {
            return None;
        }
        self.stats.errors += 1;
        if self.table[usize::from(addr::STATUS_RETURN_LEVEL)] < 2 {
            return None;
        }
        self.finish_reply(status::CRC, 0, ReplySlot::First)
    }

    fn finish_reply(&mut self, error: u8, len: usize, slot: ReplySlot) -> Option<Reply> {
        let alert = if self.hardware_error() != 0 {
            status::ALERT
        } else {
            0
        };
        let mut reply = Reply {
            id: self.id(),
            error: error | alert,
            len,
            slot,
            extra_delay: Duration::ZERO,
            corrupt_crc: false,
        };
        if let Some(f) = &mut self.fault {
            match f.fault {
                ReplyFault::Silent => reply.len = usize::MAX,
                ReplyFault::CorruptCrc => reply.corrupt_crc = true,
                ReplyFault::WrongId(other) => reply.id = other,
                ReplyFault::Delay(d) => reply.extra_delay = d,
            }
            if let Some(n) = &mut f.remaining {
                *n = n.saturating_sub(1);
                if *n == 0 {
                    self.fault = None;
                }
            }
        }
        (reply.len != usize::MAX).then_some(reply)
    }

    fn ping_reply(&mut self) -> usize {
        self.reply[..2].copy_from_slice(&self.model.model_number.to_le_bytes());
        self.reply[2] = self.model.firmware_version;
        3
    }

    fn handle_single(&mut self, packet: &Packet<'_>, now: SimInstant) -> Result<usize, u8> {
        let p = packet.params;
        match packet.instruction {
            inst::READ => {
                let [a0, a1, l0, l1] = <[u8; 4]>::try_from(p).map_err(|_| status::DATA_LENGTH)?;
                self.read_into_reply(u16::from_le_bytes([a0, a1]), u16::from_le_bytes([l0, l1]))
            }
            inst::WRITE => {
                let (address, data) = split_address(p)?;
                self.write(address, data).map(|()| 0)
            }
            inst::REG_WRITE => {
                let (address, data) = split_address(p)?;
                self.check_write(address, data)?;
                let mut buf = [0; TABLE_LEN];
                buf[..data.len()].copy_from_slice(data);
                self.registered = Some((address, data.len(), buf));
                self.table[usize::from(addr::REGISTERED_INSTRUCTION)] = 1;
                Ok(0)
            }
            inst::ACTION => {
                let (address, len, buf) = self.registered.take().ok_or(status::INSTRUCTION)?;
                self.table[usize::from(addr::REGISTERED_INSTRUCTION)] = 0;
                self.write(address, &buf[..len]).map(|()| 0)
            }
            inst::REBOOT => {
                self.offline_until = Some(now + self.config.boot_time);
                self.table[usize::from(addr::HARDWARE_ERROR_STATUS)] = 0;
                self.reset_ram();
                self.boot_turn_pending = true;
                Ok(0)
            }
            inst::FACTORY_RESET => {
                let &[kind] = p else {
                    return Err(status::DATA_LENGTH);
                };
                if !matches!(kind, 0x01 | 0x02 | 0xFF) {
                    return Err(status::DATA_RANGE);
                }
                if self.torque_enabled() {
                    return Err(status::ACCESS);
                }
                self.factory_reset(kind);
                self.offline_until = Some(now + self.config.boot_time);
                Ok(0)
            }
            inst::CLEAR => {
                // Clear Multi-Turn: 01 44 58 4C 22 ("DXL\""), accepted while not moving.
                if p != [0x01, 0x44, 0x58, 0x4C, 0x22] {
                    return Err(status::DATA_RANGE);
                }
                if self.reg(addr::MOVING) != 0 {
                    return Err(status::RESULT_FAIL);
                }
                let present = self.reg(addr::PRESENT_POSITION);
                self.multi_turn_base -= present.div_euclid(4096) * 4096;
                Ok(0)
            }
            _ => Err(status::INSTRUCTION),
        }
    }

    /// Sync/bulk instructions sent to the broadcast ID. `None`: this servo is not in the list.
    fn handle_group(&mut self, packet: &Packet<'_>) -> Option<(Result<usize, u8>, ReplySlot)> {
        let id = self.id();
        let p = packet.params;
        match packet.instruction {
            inst::SYNC_READ | inst::FAST_SYNC_READ => {
                let (address, len, ids) = split_sync_header(p)?;
                let index = ids.iter().position(|&i| i == id)?;
                let slot = if packet.instruction == inst::FAST_SYNC_READ {
                    ReplySlot::Fast(index)
                } else {
                    ReplySlot::InList(index)
                };
                Some((self.read_into_reply(address, len), slot))
            }
            inst::SYNC_WRITE => {
                let (address, len, body) = split_sync_header(p)?;
                let stride = usize::from(len) + 1;
                if len == 0 || !body.len().is_multiple_of(stride) {
                    return None;
                }
                let chunk = body.chunks_exact(stride).find(|c| c[0] == id)?;
                // Sync write has no status packet; errors only show in the servo's counters.
                Some((self.write(address, &chunk[1..]).map(|()| 0), ReplySlot::First))
            }
            inst::BULK_READ | inst::FAST_BULK_READ => {
                if !p.len().is_multiple_of(5) {
                    return None;
                }
                let (index, entry) = p.chunks_exact(5).enumerate().find(|(_, c)| c[0] == id)?;
                let address = u16::from_le_bytes([entry[1], entry[2]]);
                let len = u16::from_le_bytes([entry[3], entry[4]]);
                let slot = if packet.instruction == inst::FAST_BULK_READ {
                    ReplySlot::Fast(index)
                } else {
                    ReplySlot::InList(index)
                };
                Some((self.read_into_reply(address, len), slot))
            }
            _ => {
                // Bulk write: [id, addr, len, data…] repeated.
                let mut rest = p;
                while rest.len() >= 5 {
                    let address = u16::from_le_bytes([rest[1], rest[2]]);
                    let len = usize::from(u16::from_le_bytes([rest[3], rest[4]]));
                    let data = rest.get(5..5 + len)?;
                    if rest[0] == id {
                        return Some((self.write(address, data).map(|()| 0), ReplySlot::First));
                    }
                    rest = &rest[5 + len..];
                }
                None
            }
        }
    }

    fn read_into_reply(&mut self, address: u16, len: u16) -> Result<usize, u8> {
        let (start, len) = (usize::from(address), usize::from(len));
        if len == 0 || start + len > TABLE_LEN {
            return Err(status::DATA_RANGE);
        }
        for i in 0..len {
            let at = self.resolve(start + i);
            self.reply[i] = at.map_or(0, |a| self.table[a]);
        }
        Ok(len)
    }

    /// The table byte standing behind `address`, following indirect data to its target.
    fn resolve(&self, address: usize) -> Option<usize> {
        let first = usize::from(addr::INDIRECT_DATA_1);
        if address >= TABLE_LEN {
            return None;
        }
        if address < first {
            return Some(address);
        }
        let at = usize::from(addr::INDIRECT_ADDRESS_1) + 2 * (address - first);
        let target = usize::from(u16::from_le_bytes([self.table[at], self.table[at + 1]]));
        match target {
            // The factory setting points each data byte at itself: plain storage.
            t if t >= first && t < TABLE_LEN => Some(address),
            t if t < TABLE_LEN => Some(t),
            _ => None,
        }
    }

    fn write(&mut self, address: u16, data: &[u8]) -> Result<(), u8> {
        let staged = self.check_write(address, data)?;
        let was_on = self.torque_enabled();
        let old_watchdog = self.table[usize::from(addr::BUS_WATCHDOG)];
        let mode_written = (address..address + data.len() as u16).contains(&addr::OPERATING_MODE);
        self.table = staged;
        if mode_written {
            // A change of Operating Mode resets the turn count: Present Position (Homing Offset
            // included) comes back within one turn at the next sample.
            self.boot_turn_pending = true;
        }
        self.persist_side_effects(was_on, old_watchdog);
        Ok(())
    }

    /// Validates a write as the firmware does (whole fields, access, ranges, limits) and returns
    /// the table it would leave.
    fn check_write(&self, address: u16, data: &[u8]) -> Result<[u8; TABLE_LEN], u8> {
        let start = usize::from(address);
        if data.is_empty() {
            return Err(status::DATA_LENGTH);
        }
        if start + data.len() > TABLE_LEN {
            return Err(status::DATA_RANGE);
        }
        let mut staged = self.table;
        let mut written = [false; TABLE_LEN];
        // The span of table bytes the write reaches (indirect data reaches anywhere): only the
        // fields within it are checked.
        let (mut lo, mut hi) = (TABLE_LEN, 0);
        for (i, &byte) in data.iter().enumerate() {
            let Some(target) = self.resolve(start + i) else {
                return Err(status::DATA_RANGE);
            };
            staged[target] = byte;
            written[target] = true;
            (lo, hi) = (lo.min(target), hi.max(target + 1));
        }
        let torque_on = self.torque_enabled();
        let watchdog_expired = self.reg(addr::BUS_WATCHDOG) == -1;
        let mut at = table::field_at(lo as u16).map_or(lo, |f| usize::from(f.addr));
        while at < hi {
            let Some(field) = table::field_at(at as u16) else {
                // Bytes outside any field keep their value.
                staged[at] = self.table[at];
                at += 1;
                continue;
            };
            let range = usize::from(field.addr)..usize::from(field.addr) + usize::from(field.size);
            at = range.end;
            let touched = written[range.clone()].iter().filter(|&&w| w).count();
            if touched == 0 {
                continue;
            }
            if touched < range.len() {
                return Err(status::DATA_LENGTH);
            }
            if field.access == Access::Read
                || (field.needs_current_sensing && !self.model.current_sensing)
                || (field.addr < table::RAM_START && torque_on)
            {
                return Err(status::ACCESS);
            }
            let value = table::read_field(&staged, field);
            if value < field.min || value > field.max {
                return Err(status::DATA_RANGE);
            }
            self.check_limits(field, value, &staged, watchdog_expired)?;
        }
        Ok(staged)
    }

    fn check_limits(
        &self,
        field: Field,
        value: i64,
        staged: &[u8],
        watchdog_expired: bool,
    ) -> Result<(), u8> {
        let staged_reg = |a: u16| table::read_field(staged, table::field_at(a).expect("known field"));
        let is_goal = matches!(
            field.addr,
            addr::GOAL_PWM | addr::GOAL_CURRENT | addr::GOAL_VELOCITY | addr::GOAL_POSITION
        );
        if is_goal && watchdog_expired {
            return Err(status::DATA_RANGE);
        }
        let within = |limit: i64| {
            if value.abs() <= limit {
                Ok(())
            } else {
                Err(status::DATA_LIMIT)
            }
        };
        match field.addr {
            addr::OPERATING_MODE => {
                let allowed: &[i64] = if self.model.current_sensing {
                    &[0, 1, 3, 4, 5, 16]
                } else {
                    &[1, 3, 4, 16]
                };
                if allowed.contains(&value) {
                    Ok(())
                } else {
                    Err(status::DATA_RANGE)
                }
            }
            addr::BUS_WATCHDOG => {
                // -1 is the firmware's own marker; the host may write 0 (clear/disable) or 1..127.
                if value >= 0 {
                    Ok(())
                } else {
                    Err(status::DATA_RANGE)
                }
            }
            addr::TORQUE_ENABLE if value == 1 && self.shutdown_active() => Err(status::RESULT_FAIL),
            addr::GOAL_PWM => within(staged_reg(addr::PWM_LIMIT)),
            addr::GOAL_CURRENT => within(staged_reg(addr::CURRENT_LIMIT)),
            addr::GOAL_VELOCITY => within(staged_reg(addr::VELOCITY_LIMIT)),
            addr::GOAL_POSITION if staged_reg(addr::OPERATING_MODE) == 3 => {
                let (lo, hi) = (
                    staged_reg(addr::MIN_POSITION_LIMIT),
                    staged_reg(addr::MAX_POSITION_LIMIT),
                );
                if (lo..=hi).contains(&value) {
                    Ok(())
                } else {
                    Err(status::DATA_LIMIT)
                }
            }
            _ => Ok(()),
        }
    }

    fn persist_side_effects(&mut self, was_on: bool, _old_watchdog: u8) {
        let on = self.torque_enabled();
        if on && !was_on {
            // Torque on: hold where the horn is, with fresh integrators.
            let present = self.reg(addr::PRESENT_POSITION);
            self.set_reg(addr::GOAL_POSITION, present);
            self.position_integral = 0.0;
            self.velocity_integral = 0.0;
            self.previous_error = 0.0;
        }
    }

    // ---------------------------------------------------------------- control loop

    /// Runs one control period at `now`: samples the plant, updates the present values, checks
    /// the watchdog and protections, and applies the motor torque for the next period.
    pub fn tick(&mut self, now: SimInstant, plant: &mut dyn MotorPlant) {
        let dt = self.config.control_period.as_secs_f64();
        self.stats.control_ticks += 1;
        if self.vanished || !self.is_online(now) {
            plant.apply_torque(0.0);
            return;
        }
        if self.offline_until.is_some() {
            // Boot finished: the watchdog counts from now.
            self.offline_until = None;
            self.last_instruction_at = now;
        }
        let m = &self.model;
        let (kt, resistance, back_emf) = (m.torque_constant(), m.resistance(), m.back_emf());
        let reverse = if self.table[usize::from(addr::DRIVE_MODE)] & 1 == 1 {
            -1.0
        } else {
            1.0
        };
        // Encoder and motor see the shaft through the drive-mode direction.
        let shaft = reverse * plant.position();
        let omega = reverse * plant.velocity();
        let ticks_exact = f64::from(self.config.mount_offset_ticks) + shaft / models::rad_per_tick();
        let homed = ticks_exact.round() as i64 + self.reg(addr::HOMING_OFFSET);
        if std::mem::take(&mut self.boot_turn_pending) {
            // A joint whose range crosses this wrap point reads a turn off after power-up:
            // calibration sets the Homing Offset to keep it outside the range.
            self.multi_turn_base = -homed.div_euclid(4096) * 4096;
        }
        let present = homed + self.multi_turn_base;
        let velocity_units = omega / models::rad_s_per_velocity_unit();
        self.set_reg(addr::PRESENT_POSITION, present);
        self.set_reg(addr::PRESENT_VELOCITY, velocity_units.round() as i64);
        self.set_reg(
            addr::PRESENT_INPUT_VOLTAGE,
            (self.config.supply_voltage * 10.0).round() as i64,
        );
        self.set_reg(addr::REALTIME_TICK, (now.as_nanos() / 1_000_000 % 32768) as i64);
        let moving = velocity_units.abs() > self.reg(addr::MOVING_THRESHOLD) as f64;
        self.set_reg(addr::MOVING, i64::from(moving));

        self.check_watchdog(now);
        let supply = self.config.supply_voltage;
        let voltage_ok = (self.reg(addr::MIN_VOLTAGE_LIMIT) as f64
            ..=self.reg(addr::MAX_VOLTAGE_LIMIT) as f64)
            .contains(&(supply * 10.0));
        if !voltage_ok {
            self.raise_hardware_error(hw::VOLTAGE);
        }

        let pwm_limit = self.reg(addr::PWM_LIMIT) as f64;
        let current_limit = if self.model.current_sensing {
            self.reg(addr::CURRENT_LIMIT) as f64 * models::CURRENT_UNIT_A
        } else {
            f64::INFINITY
        };
        let mut current = 0.0;
        let mut pwm = 0.0;
        if self.torque_enabled() {
            let mode = self.reg(addr::OPERATING_MODE);
            // The current that flows when the bridge applies duty `pwm` (quasi-static winding).
            let current_at = |pwm: f64| (pwm / PWM_FULL_SCALE * supply - back_emf * omega) / resistance;
            match mode {
                0 => {
                    let goal = self.reg(addr::GOAL_CURRENT) as f64 * models::CURRENT_UNIT_A;
                    pwm = ((goal * resistance + back_emf * omega) / supply * PWM_FULL_SCALE)
                        .clamp(-pwm_limit, pwm_limit);
                }
                1 => {
                    let error = self.reg(addr::GOAL_VELOCITY) as f64 - velocity_units;
                    self.velocity_integral += error;
                    let [vp, vi] = [self.reg(addr::VELOCITY_P_GAIN), self.reg(addr::VELOCITY_I_GAIN)];
                    pwm = (vp as f64 / 128.0 * error + vi as f64 / 65536.0 * self.velocity_integral)
                        .clamp(-pwm_limit, pwm_limit);
                }
                16 => pwm = (self.reg(addr::GOAL_PWM) as f64).clamp(-pwm_limit, pwm_limit),
                _ => {
                    // Position (3), extended position (4), current-based position (5).
                    let error = (self.reg(addr::GOAL_POSITION) - present) as f64;
                    self.position_integral += error;
                    let derivative = error - self.previous_error;
                    self.previous_error = error;
                    let [p, i, d] = [
                        self.reg(addr::POSITION_P_GAIN),
                        self.reg(addr::POSITION_I_GAIN),
                        self.reg(addr::POSITION_D_GAIN),
                    ];
                    let out = p as f64 / 128.0 * error
                        + i as f64 / 65536.0 * self.position_integral
                        + d as f64 / 16.0 * derivative;
                    pwm = out.clamp(-pwm_limit, pwm_limit);
                    if mode == 5 {
                        // The position loop's output is a current, capped by Goal Current.
                        let cap = (self.reg(addr::GOAL_CURRENT) as f64 * models::CURRENT_UNIT_A).abs();
                        let wanted = (out / PWM_FULL_SCALE * supply / resistance).clamp(-cap, cap);
                        pwm = ((wanted * resistance + back_emf * omega) / supply * PWM_FULL_SCALE)
                            .clamp(-pwm_limit, pwm_limit);
                    }
                }
            }
            current = current_at(pwm).clamp(-current_limit, current_limit);
        } else {
            self.previous_error = 0.0;
        }
        let mut torque = kt * current;
        self.applied_torque = torque;
        plant.apply_torque(reverse * torque);
        if let Some(acted) = self.sensed_torque.filter(|_| self.torque_enabled()) {
            torque = reverse * acted;
            current = torque / kt;
        }
        self.set_reg(addr::PRESENT_PWM, pwm.round() as i64);
        let reported = if self.model.current_sensing {
            current / models::CURRENT_UNIT_A
        } else {
            // XL: Present Load in 0.1 % of the maximum torque.
            torque / self.model.stall_torque * 1000.0
        };
        self.set_reg(
            addr::PRESENT_CURRENT,
            reported.round().clamp(-32768.0, 32767.0) as i64,
        );

        // Thermal model and protections.
        let heat = current * current * resistance;
        let cooling = (self.temperature - self.config.ambient_temperature) / self.config.thermal_resistance;
        self.temperature += (heat - cooling) / self.config.thermal_capacity * dt;
        self.set_reg(
            addr::PRESENT_TEMPERATURE,
            self.temperature.round().clamp(0.0, 255.0) as i64,
        );
        if self.temperature > self.reg(addr::TEMPERATURE_LIMIT) as f64 {
            self.raise_hardware_error(hw::OVERHEAT);
        }
        let stalled =
            pwm.abs() >= 0.98 * pwm_limit && omega.abs() < 0.1 * self.model.no_load_speed * TAU / 60.0;
        self.overload_seconds = if stalled && pwm_limit > 0.0 {
            self.overload_seconds + dt
        } else {
            0.0
        };
        if self.overload_seconds > 1.5 {
            self.raise_hardware_error(hw::OVERLOAD);
        }
    }

    fn check_watchdog(&mut self, now: SimInstant) {
        let setting = self.reg(addr::BUS_WATCHDOG);
        if setting <= 0 || !self.torque_enabled() {
            return;
        }
        let limit = Duration::from_millis(20 * setting as u64);
        if now.saturating_since(self.last_instruction_at) > limit {
            self.stats.watchdog_expiries += 1;
            self.set_reg(addr::BUS_WATCHDOG, -1);
            self.table[usize::from(addr::TORQUE_ENABLE)] = 0;
        }
    }
}

fn split_address(p: &[u8]) -> Result<(u16, &[u8]), u8> {
    if p.len() < 3 {
        return Err(status::DATA_LENGTH);
    }
    Ok((u16::from_le_bytes([p[0], p[1]]), &p[2..]))
}

fn split_sync_header(p: &[u8]) -> Option<(u16, u16, &[u8])> {
    (p.len() >= 5).then(|| {
        (
            u16::from_le_bytes([p[0], p[1]]),
            u16::from_le_bytes([p[2], p[3]]),
            &p[4..],
        )
    })
}
