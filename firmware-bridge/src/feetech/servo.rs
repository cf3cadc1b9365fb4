//! An emulated Feetech STS servo: its control table, what it does with each instruction, and the
//! position loop it runs on its shaft.
//!
//! - Instructions: PING, READ, WRITE, REG_WRITE + ACTION, RESET, SYNC_READ (answers in its place
//!   in the list), SYNC_WRITE. Instructions to the broadcast ID get no answer; with Response Level
//!   0 only PING and READ are answered.
//! - EPROM (below 40): writes take effect at once; they survive [`StsServo::power_cycle`] only
//!   while Lock (55) is 0, as on the servo. Read-only addresses ignore writes.
//! - Sign-magnitude values (position, speed: bit 15; load: bit 10; homing offset: bit 11).
//! - Position mode: Present Position = encoder − Homing Offset within one turn (0…4095); the loop
//!   drives the duty from the error (P), the speed (D) and its sum (I), limited by Torque Limit;
//!   Goal Speed and Acceleration shape the setpoint; the angle limits clamp the goal. Torque
//!   Enable 128 takes the present position as the middle (2048) through the homing offset.
//! - Protections: temperature over its limit (overheat), supply outside the voltage limits,
//!   output held above the overload threshold for the protection time (overload: output falls
//!   to the protective torque). An error bit set in the unloading condition (19) switches the
//!   output off. The status packet's error byte carries the bits in force.

use std::time::Duration;

use super::models::FeetechModel;
use super::packet::{self, error, from_sign_magnitude, inst, to_sign_magnitude};
use super::table::{self, addr};
use crate::half_duplex::ReplyFault;
use crate::plant::MotorPlant;
use crate::time::SimInstant;

/// Where a servo's answer goes on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplySlot {
    /// Right after the instruction.
    First,
    /// After the servos listed before it in a sync read (0-based place).
    InList(usize),
}

/// A status packet a servo wants to send, its parameters in [`StsServo::reply_params`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Reply {
    /// ID in the status packet.
    pub id: u8,
    /// Error byte.
    pub error: u8,
    /// Parameter bytes.
    pub len: usize,
    /// Order on the wire.
    pub slot: ReplySlot,
    /// Extra delay before it (injected fault).
    pub extra_delay: Duration,
    /// Corrupt its checksum (injected fault).
    pub corrupt_checksum: bool,
}

/// How a servo sits on its line and in its mechanism.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StsConfig {
    /// ID (factory: 1).
    pub id: u8,
    /// Baud rate index (factory: 0, 1 Mbit/s).
    pub baud_index: u8,
    /// Return delay, 2 µs units (factory: 0).
    pub return_delay: u8,
    /// Supply voltage, V.
    pub supply_voltage: f64,
    /// Encoder reading at the plant's zero angle, ticks (how the horn was mounted).
    pub mount_offset_ticks: i32,
    /// Firmware period.
    pub control_period: Duration,
    /// Ambient temperature, °C.
    pub ambient_temperature: f64,
    /// Thermal resistance winding → ambient, K/W.
    pub thermal_resistance: f64,
    /// Thermal capacity, J/K.
    pub thermal_capacity: f64,
}

impl StsConfig {
    /// Servo `id` at 1 Mbit/s with no return delay, at its model's voltage, horn at the centre.
    pub fn new(id: u8, model: &FeetechModel) -> Self {
        Self {
            id,
            baud_index: 0,
            return_delay: 0,
            supply_voltage: model.nominal_voltage,
            mount_offset_ticks: 2048,
            control_period: Duration::from_millis(1),
            ambient_temperature: 25.0,
            thermal_resistance: 8.0,
            thermal_capacity: 25.0,
        }
    }
}

/// Counters of what a servo saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StsStats {
    /// Packets addressed to it (directly, by broadcast, or in a sync list).
    pub packets: u64,
    /// Status packets it sent.
    pub replies: u64,
    /// Control periods run.
    pub control_ticks: u64,
}

/// One emulated STS servo.
#[derive(Debug, Clone)]
pub struct StsServo {
    model: FeetechModel,
    config: StsConfig,
    table: [u8; table::TABLE_LEN],
    /// EPROM as kept over a power cycle.
    saved: [u8; table::SRAM_START as usize],
    /// A REG_WRITE waiting for ACTION: address, data, length.
    held: Option<(u8, [u8; 256], usize)>,
    reply: [u8; 256],
    /// The position setpoint the loop tracks (ticks), moving towards the goal.
    setpoint: f64,
    setpoint_speed: f64,
    integral: f64,
    temperature: f64,
    applied_torque: f64,
    /// The torque that acted on the shaft, N·m, where a simulator applies its own servo model
    /// (see [`Self::sense_torque`]): what the current sensor reports instead of the emulated loop's.
    sensed_torque: Option<f64>,
    overload_seconds: f64,
    fault: Option<(ReplyFault, Option<u32>)>,
    vanished: bool,
    stats: StsStats,
}

fn word(table: &[u8], at: u8) -> u16 {
    u16::from_le_bytes([table[usize::from(at)], table[usize::from(at) + 1]])
}

fn set_word(table: &mut [u8], at: u8, v: u16) {
    table[usize::from(at)..usize::from(at) + 2].copy_from_slice(&v.to_le_bytes());
}

/// Addresses the host may write (the rest are read-only).
fn writable(a: u8) -> bool {
    !matches!(a, 0..=4 | 56..=70)
}

impl StsServo {
    /// A servo fresh from the factory, but for `config`'s ID, baud and return delay.
    pub fn new(model: &FeetechModel, config: StsConfig) -> Self {
        let mut t = [0u8; table::TABLE_LEN];
        t[usize::from(addr::FIRMWARE_MAJOR)] = model.firmware[0];
        t[usize::from(addr::FIRMWARE_MINOR)] = model.firmware[1];
        set_word(&mut t, addr::MODEL, model.model_number);
        t[usize::from(addr::ID)] = config.id;
        t[usize::from(addr::BAUD)] = config.baud_index;
        t[usize::from(addr::RETURN_DELAY)] = config.return_delay;
        t[usize::from(addr::RESPONSE_LEVEL)] = 1;
        set_word(&mut t, addr::MAX_ANGLE, 4095);
        t[usize::from(addr::MAX_TEMPERATURE)] = 70;
        t[usize::from(addr::MAX_VOLTAGE)] = model.max_voltage;
        t[usize::from(addr::MIN_VOLTAGE)] = model.min_voltage;
        set_word(&mut t, addr::MAX_TORQUE, 1000);
        // Overheat, overcurrent and overload switch the output off.
        t[usize::from(addr::UNLOADING)] = error::OVERHEAT | error::OVERCURRENT | error::OVERLOAD;
        t[usize::from(addr::P_GAIN)] = 32;
        t[usize::from(addr::D_GAIN)] = 32;
        t[usize::from(addr::PROTECTIVE_TORQUE)] = 20;
        t[usize::from(addr::PROTECTION_TIME)] = 200;
        t[usize::from(addr::OVERLOAD_TORQUE)] = 80;
        set_word(&mut t, addr::TORQUE_LIMIT, 1000);
        t[usize::from(addr::LOCK)] = 1;
        let mut saved = [0u8; table::SRAM_START as usize];
        saved.copy_from_slice(&t[..table::SRAM_START as usize]);
        Self {
            model: model.clone(),
            config,
            table: t,
            saved,
            held: None,
            reply: [0; 256],
            setpoint: f64::NAN,
            setpoint_speed: 0.0,
            integral: 0.0,
            temperature: config.ambient_temperature,
            applied_torque: 0.0,
            sensed_torque: None,
            overload_seconds: 0.0,
            fault: None,
            vanished: false,
            stats: StsStats::default(),
        }
    }

    /// The model.
    pub fn model(&self) -> &FeetechModel {
        &self.model
    }

    /// Its ID.
    pub fn id(&self) -> u8 {
        self.table[usize::from(addr::ID)]
    }

    /// Its baud rate.
    pub fn baud(&self) -> Option<u32> {
        table::baud_of_index(self.table[usize::from(addr::BAUD)])
    }

    /// How long it waits before answering.
    pub fn return_delay(&self) -> Duration {
        Duration::from_micros(2 * u64::from(self.table[usize::from(addr::RETURN_DELAY)]))
    }

    /// One byte of the table.
    pub fn register(&self, address: u8) -> u8 {
        self.table[usize::from(address)]
    }

    /// Whether the output is on.
    pub fn torque_enabled(&self) -> bool {
        self.table[usize::from(addr::TORQUE_ENABLE)] == 1
    }

    /// The error bits in force (Status, 65).
    pub fn status(&self) -> u8 {
        self.table[usize::from(addr::STATUS)]
    }

    /// Torque at the output in the last period, N·m.
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

    /// The most torque it gives now, N·m: stall torque scaled by Torque Limit.
    pub fn torque_cap(&self) -> f64 {
        f64::from(word(&self.table, addr::TORQUE_LIMIT).min(1000)) / 1000.0 * self.model.stall_torque
    }

    /// Winding temperature, °C.
    pub fn temperature(&self) -> f64 {
        self.temperature
    }

    /// Counters.
    pub fn stats(&self) -> StsStats {
        self.stats
    }

    /// The stiffness (N·m/rad) and damping (N·m·s/rad) at the output that its P and D gains
    /// give, at stall and nominal supply (duty per tick of error and per tick/s of speed; full
    /// duty gives the stall torque): what a simulator's position actuator applies while it
    /// tracks [`Self::position_goal`].
    pub fn position_stiffness(&self) -> [f64; 2] {
        let [p, d] = [addr::P_GAIN, addr::D_GAIN].map(|a| f64::from(self.table[usize::from(a)]));
        let per_tick = table::rad_per_tick();
        [
            p * table::P_DUTY_PER_TICK * self.model.stall_torque / per_tick,
            d * table::D_DUTY_PER_TICK_PER_S * self.model.stall_torque / per_tick,
        ]
    }

    /// The plant angle (rad) it is holding towards while its output is on in position mode:
    /// what a simulator's position actuator tracks instead of the duty law.
    pub fn position_goal(&self) -> Option<f64> {
        if !self.torque_enabled() || self.table[usize::from(addr::MODE)] != 0 || self.setpoint.is_nan() {
            return None;
        }
        let offset = from_sign_magnitude(word(&self.table, addr::HOMING_OFFSET), 11);
        let raw = self.setpoint + f64::from(offset) - f64::from(self.config.mount_offset_ticks);
        Some(raw * table::rad_per_tick())
    }

    /// The parameters of `reply`.
    pub fn reply_params(&self, reply: &Reply) -> &[u8] {
        &self.reply[..reply.len]
    }

    /// Injects a reply fault (replacing any other) for `count` answers (`None`: until cleared).
    pub fn inject(&mut self, fault: ReplyFault, count: Option<u32>) {
        self.fault = Some((fault, count));
    }

    /// Clears injected reply faults.
    pub fn clear_faults(&mut self) {
        self.fault = None;
    }

    /// Raises error bits as the firmware would on detecting them.
    pub fn raise_error(&mut self, bits: u8) {
        self.table[usize::from(addr::STATUS)] |= bits;
    }

    /// The servo loses power for good: no answers, no torque.
    pub fn vanish(&mut self) {
        self.vanished = true;
        self.table[usize::from(addr::TORQUE_ENABLE)] = 0;
    }

    /// Power off and on: SRAM back to its power-up values, EPROM to what was kept.
    pub fn power_cycle(&mut self) {
        let fresh = Self::new(&self.model, self.config);
        self.table = fresh.table;
        self.table[..table::SRAM_START as usize].copy_from_slice(&self.saved);
        let max_torque = word(&self.table, addr::MAX_TORQUE);
        set_word(&mut self.table, addr::TORQUE_LIMIT, max_torque);
        self.held = None;
        self.setpoint = f64::NAN;
    }

    /// What the servo does with an instruction packet to `id`; its answer, if it gives one.
    pub fn handle(&mut self, id: u8, instruction: u8, params: &[u8]) -> Option<Reply> {
        if self.vanished {
            return None;
        }
        let me = self.id();
        if instruction == inst::SYNC_READ || instruction == inst::SYNC_WRITE {
            return if id == packet::BROADCAST_ID {
                self.handle_sync(instruction, params)
            } else {
                None
            };
        }
        if id != me && id != packet::BROADCAST_ID {
            return None;
        }
        self.stats.packets += 1;
        let len = match instruction {
            inst::PING => 0,
            inst::READ => match params {
                [a, n] if usize::from(*a) + usize::from(*n) <= table::TABLE_LEN => {
                    let (a, n) = (usize::from(*a), usize::from(*n));
                    self.reply[..n].copy_from_slice(&self.table[a..a + n]);
                    n
                }
                // Outside the table: an empty answer, which hosts refuse by its length.
                _ => 0,
            },
            inst::WRITE => {
                if let Some((&a, data)) = params.split_first() {
                    self.write(a, data);
                }
                0
            }
            inst::REG_WRITE => {
                if let Some((&a, data)) = params.split_first() {
                    let mut held = [0u8; 256];
                    held[..data.len()].copy_from_slice(data);
                    self.held = Some((a, held, data.len()));
                }
                0
            }
            inst::ACTION => {
                if let Some((a, data, n)) = self.held.take() {
                    self.write(a, &data[..n]);
                }
                0
            }
            inst::RESET => {
                let keep = (self.id(), self.table[usize::from(addr::BAUD)]);
                let fresh = Self::new(&self.model, self.config);
                self.table = fresh.table;
                self.table[usize::from(addr::ID)] = keep.0;
                self.table[usize::from(addr::BAUD)] = keep.1;
                0
            }
            _ => return None,
        };
        let answers = instruction == inst::PING
            || instruction == inst::READ
            || self.table[usize::from(addr::RESPONSE_LEVEL)] != 0;
        if id == packet::BROADCAST_ID || !answers {
            return None;
        }
        self.finish(len, ReplySlot::First)
    }

    fn handle_sync(&mut self, instruction: u8, params: &[u8]) -> Option<Reply> {
        let [a, n, rest @ ..] = params else { return None };
        let (a, n) = (*a, usize::from(*n));
        let me = self.id();
        if instruction == inst::SYNC_WRITE {
            // `(id, data[n])…`; a short list ends where its data runs out.
            if n == 0 {
                return None;
            }
            if let Some(chunk) = rest.chunks_exact(n + 1).find(|c| c[0] == me) {
                self.stats.packets += 1;
                self.write(a, &chunk[1..]);
            }
            return None;
        }
        let place = rest.iter().position(|&i| i == me)?;
        self.stats.packets += 1;
        if usize::from(a) + n > table::TABLE_LEN {
            return None;
        }
        self.reply[..n].copy_from_slice(&self.table[usize::from(a)..usize::from(a) + n]);
        self.finish(n, ReplySlot::InList(place))
    }

    fn finish(&mut self, len: usize, slot: ReplySlot) -> Option<Reply> {
        let mut reply = Reply {
            id: self.id(),
            error: self.status(),
            len,
            slot,
            extra_delay: Duration::ZERO,
            corrupt_checksum: false,
        };
        if let Some((fault, remaining)) = self.fault {
            match fault {
                ReplyFault::Silent => reply.len = usize::MAX,
                ReplyFault::CorruptCrc => reply.corrupt_checksum = true,
                ReplyFault::WrongId(id) => reply.id = id,
                ReplyFault::Delay(d) => reply.extra_delay = d,
            }
            self.fault = match remaining {
                Some(1) => None,
                Some(k) => Some((fault, Some(k - 1))),
                None => Some((fault, None)),
            };
            if reply.len == usize::MAX {
                return None;
            }
        }
        self.stats.replies += 1;
        Some(reply)
    }

    fn write(&mut self, a: u8, data: &[u8]) {
        let was_on = self.torque_enabled();
        for (k, &v) in data.iter().enumerate() {
            let Some(at) = a
                .checked_add(k as u8)
                .filter(|&at| usize::from(at) < table::TABLE_LEN)
            else {
                break;
            };
            if !writable(at) {
                continue;
            }
            // An ID of 254 (broadcast) or 255 or a baud index the servo has no rate for
            // would leave it unreachable: the firmware keeps the old value.
            if (at == addr::ID && v >= packet::BROADCAST_ID)
                || (at == addr::BAUD && table::baud_of_index(v).is_none())
            {
                continue;
            }
            if at == addr::TORQUE_ENABLE && v == 128 {
                // The present position becomes the middle of the range.
                let present = i32::from(word(&self.table, addr::PRESENT_POSITION));
                let old = from_sign_magnitude(word(&self.table, addr::HOMING_OFFSET), 11);
                let offset = (present + old - 2048).clamp(-2047, 2047);
                set_word(
                    &mut self.table,
                    addr::HOMING_OFFSET,
                    to_sign_magnitude(offset, 11),
                );
                continue;
            }
            self.table[usize::from(at)] = v;
            if at < table::SRAM_START && self.table[usize::from(addr::LOCK)] == 0 {
                self.saved[usize::from(at)] = v;
            }
        }
        if !was_on && self.torque_enabled() {
            // Output on: the setpoint starts where the shaft is, no jump.
            self.setpoint = f64::NAN;
            self.integral = 0.0;
        }
    }

    /// One control period at `now`: samples the plant, updates the present values, runs the
    /// protections and the position loop, and applies the torque for the next period.
    pub fn tick(&mut self, _now: SimInstant, plant: &mut dyn MotorPlant) {
        self.stats.control_ticks += 1;
        if self.vanished {
            plant.apply_torque(0.0);
            return;
        }
        let dt = self.config.control_period.as_secs_f64();
        let motor = self.model.motor();
        let tick_rad = table::rad_per_tick();
        let omega = plant.velocity();
        let encoder = f64::from(self.config.mount_offset_ticks) + plant.position() / tick_rad;
        let offset = from_sign_magnitude(word(&self.table, addr::HOMING_OFFSET), 11);
        let present = (encoder.round() as i32 - offset).rem_euclid(table::TICKS_PER_TURN);
        let speed = omega / tick_rad;
        set_word(&mut self.table, addr::PRESENT_POSITION, present as u16);
        set_word(
            &mut self.table,
            addr::PRESENT_SPEED,
            to_sign_magnitude(speed.round() as i32, 15),
        );
        let supply = self.config.supply_voltage;
        self.table[usize::from(addr::PRESENT_VOLTAGE)] = (supply * 10.0).round().clamp(0.0, 255.0) as u8;
        self.table[usize::from(addr::MOVING)] = u8::from(speed.abs() > 4.0);
        let volts = (supply * 10.0).round();
        let limits = f64::from(self.table[usize::from(addr::MIN_VOLTAGE)])
            ..=f64::from(self.table[usize::from(addr::MAX_VOLTAGE)]);
        if !limits.contains(&volts) {
            self.raise_error(error::VOLTAGE);
        }
        if self.status() & self.table[usize::from(addr::UNLOADING)] != 0 {
            self.table[usize::from(addr::TORQUE_ENABLE)] = 0;
        }

        let mut duty = 0.0;
        if self.torque_enabled() && self.table[usize::from(addr::MODE)] == 0 {
            let (lo, hi) = (
                word(&self.table, addr::MIN_ANGLE),
                word(&self.table, addr::MAX_ANGLE),
            );
            let mut goal = f64::from(from_sign_magnitude(word(&self.table, addr::GOAL_POSITION), 15));
            if lo != 0 || hi != 0 {
                goal = goal.clamp(f64::from(lo), f64::from(hi.max(lo)));
            }
            if self.setpoint.is_nan() {
                self.setpoint = f64::from(present);
                self.setpoint_speed = 0.0;
            }
            // The setpoint moves to the goal at Goal Speed (0: at once) with Acceleration.
            let max_speed = f64::from(word(&self.table, addr::GOAL_SPEED) & 0x7FFF);
            let accel = f64::from(self.table[usize::from(addr::ACCELERATION)]) * 100.0;
            if max_speed == 0.0 {
                self.setpoint = goal;
            } else {
                let wanted = ((goal - self.setpoint) / dt).clamp(-max_speed, max_speed);
                let step = if accel > 0.0 { accel * dt } else { f64::INFINITY };
                self.setpoint_speed += (wanted - self.setpoint_speed).clamp(-step, step);
                self.setpoint += self.setpoint_speed * dt;
            }
            let error = self.setpoint - f64::from(present);
            self.integral = (self.integral + error * dt).clamp(-1e4, 1e4);
            let [p, d, i] =
                [addr::P_GAIN, addr::D_GAIN, addr::I_GAIN].map(|a| f64::from(self.table[usize::from(a)]));
            let limit = f64::from(word(&self.table, addr::TORQUE_LIMIT).min(1000)) / 1000.0;
            let limit = if self.status() & error::OVERLOAD != 0 {
                limit.min(f64::from(self.table[usize::from(addr::PROTECTIVE_TORQUE)]) / 100.0)
            } else {
                limit
            };
            duty = (p * table::P_DUTY_PER_TICK * error - d * table::D_DUTY_PER_TICK_PER_S * speed
                + i * table::P_DUTY_PER_TICK * 1e-2 * self.integral)
                .clamp(-limit, limit);
        } else {
            self.setpoint = f64::NAN;
        }
        let mut current = motor.current(duty, supply, omega);
        let torque = motor.torque_constant() * current;
        self.applied_torque = torque;
        plant.apply_torque(torque);
        if let Some(acted) = self.sensed_torque.filter(|_| self.torque_enabled()) {
            // The load register reads the bridge's duty: the one that drives this torque.
            current = acted / motor.torque_constant();
            duty = motor.duty_for(current, supply, omega).clamp(-1.0, 1.0);
        }
        set_word(
            &mut self.table,
            addr::PRESENT_LOAD,
            to_sign_magnitude((duty * 1000.0).round() as i32, 10),
        );
        set_word(
            &mut self.table,
            addr::PRESENT_CURRENT,
            (current.abs() / table::CURRENT_UNIT_A).round().min(32767.0) as u16,
        );

        // Thermal model and protections.
        let heat = current * current * motor.resistance();
        let cooling = (self.temperature - self.config.ambient_temperature) / self.config.thermal_resistance;
        self.temperature += (heat - cooling) / self.config.thermal_capacity * dt;
        self.table[usize::from(addr::PRESENT_TEMPERATURE)] = self.temperature.round().clamp(0.0, 255.0) as u8;
        if self.temperature > f64::from(self.table[usize::from(addr::MAX_TEMPERATURE)]) {
            self.raise_error(error::OVERHEAT);
        }
        let threshold = f64::from(self.table[usize::from(addr::OVERLOAD_TORQUE)]) / 100.0;
        self.overload_seconds = if duty.abs() >= threshold && threshold > 0.0 {
            self.overload_seconds + dt
        } else {
            0.0
        };
        let allowed = f64::from(self.table[usize::from(addr::PROTECTION_TIME)]) * 0.01;
        if self.overload_seconds > allowed {
            self.raise_error(error::OVERLOAD);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::feetech::models::find;
    use crate::plant::InertiaPlant;

    fn servo() -> (StsServo, InertiaPlant) {
        let m = find("STS3215").unwrap();
        (
            StsServo::new(m, StsConfig::new(3, m)),
            InertiaPlant::new(2e-3, 0.02, 0.01, 0.0),
        )
    }

    fn run(s: &mut StsServo, p: &mut InertiaPlant, seconds: f64) {
        for _ in 0..(seconds * 1000.0) as usize {
            s.tick(SimInstant::ZERO, p);
            p.integrate(1e-3);
        }
    }

    #[test]
    fn an_id_or_baud_that_would_make_it_unreachable_is_not_taken() {
        let (mut s, _) = servo();
        let baud = s.table[usize::from(addr::BAUD)];
        for (at, v) in [
            (addr::ID, 254),
            (addr::ID, 255),
            (addr::BAUD, 200),
            (addr::BAUD, 8),
        ] {
            s.handle(3, inst::WRITE, &[addr::LOCK, 0]);
            s.handle(3, inst::WRITE, &[at, v]);
            assert_eq!(s.id(), 3, "after writing {v} at {at}");
            assert_eq!(
                s.table[usize::from(addr::BAUD)],
                baud,
                "after writing {v} at {at}"
            );
        }
        // A good ID is taken, and the servo answers to it.
        s.handle(3, inst::WRITE, &[addr::ID, 9]);
        assert_eq!(s.id(), 9);
        assert!(s.handle(9, inst::PING, &[]).is_some());
    }

    #[test]
    fn it_answers_reads_and_moves_to_a_goal_within_its_torque_limit() {
        let (mut s, mut p) = servo();
        run(&mut s, &mut p, 0.01);
        // Model number 777 at address 3, little-endian.
        let r = s.handle(3, inst::READ, &[addr::MODEL, 2]).unwrap();
        assert_eq!(s.reply_params(&r), &777u16.to_le_bytes());
        assert_eq!(word(&s.table, addr::PRESENT_POSITION), 2048);
        s.handle(3, inst::WRITE, &[addr::TORQUE_ENABLE, 1]).unwrap();
        // Goal 2048 + 512 ticks (45°).
        s.handle(3, inst::WRITE, &[addr::GOAL_POSITION, 0x00, 0x0A])
            .unwrap();
        run(&mut s, &mut p, 1.0);
        let present = i32::from(word(&s.table, addr::PRESENT_POSITION));
        assert!((present - 2560).abs() <= 12, "{present}");
        assert!((p.q - std::f64::consts::FRAC_PI_4).abs() < 0.02, "{}", p.q);
        // A Torque Limit of 10 % caps the output against a held shaft.
        s.handle(3, inst::WRITE, &[addr::TORQUE_LIMIT, 100, 0]).unwrap();
        s.handle(3, inst::WRITE, &[addr::GOAL_POSITION, 0x00, 0x08])
            .unwrap();
        s.tick(SimInstant::ZERO, &mut InertiaPlant::new(1e3, 0.0, 0.0, p.q));
        assert!(
            s.applied_torque().abs() <= 0.1 * 1.91 + 1e-9,
            "{}",
            s.applied_torque()
        );
        // Negative goals are sign-magnitude: bit 15.
        s.handle(3, inst::WRITE, &[addr::GOAL_SPEED, 0x64, 0x80]).unwrap();
        assert_eq!(from_sign_magnitude(word(&s.table, addr::GOAL_SPEED), 15), -100);
    }

    #[test]
    fn eprom_writes_survive_a_power_cycle_only_unlocked() {
        let (mut s, _) = servo();
        s.handle(3, inst::WRITE, &[addr::RETURN_DELAY, 10]).unwrap();
        assert_eq!(s.return_delay(), Duration::from_micros(20));
        s.power_cycle();
        assert_eq!(s.register(addr::RETURN_DELAY), 0, "locked: not kept");
        s.handle(3, inst::WRITE, &[addr::LOCK, 0]).unwrap();
        s.handle(3, inst::WRITE, &[addr::RETURN_DELAY, 10]).unwrap();
        s.handle(3, inst::WRITE, &[addr::LOCK, 1]).unwrap();
        s.power_cycle();
        assert_eq!(s.register(addr::RETURN_DELAY), 10);
        // Read-only: the model number stays.
        s.handle(3, inst::WRITE, &[addr::MODEL, 1, 2]).unwrap();
        assert_eq!(word(&s.table, addr::MODEL), 777);
    }

    #[test]
    fn sync_read_and_write_use_the_list_and_response_level_quiets_writes() {
        let (mut s, _) = servo();
        // `[addr, len, id…]`: servo 3 is second in the list.
        let r = s
            .handle(
                packet::BROADCAST_ID,
                inst::SYNC_READ,
                &[addr::PRESENT_POSITION, 2, 1, 3, 5],
            )
            .unwrap();
        assert_eq!(r.slot, ReplySlot::InList(1));
        assert!(
            s.handle(packet::BROADCAST_ID, inst::SYNC_READ, &[56, 2, 1, 5])
                .is_none()
        );
        // `[addr, len, (id, data)…]`, no answer.
        let none = s.handle(
            packet::BROADCAST_ID,
            inst::SYNC_WRITE,
            &[addr::GOAL_POSITION, 2, 1, 0, 4, 3, 0x34, 0x12],
        );
        assert!(none.is_none());
        assert_eq!(word(&s.table, addr::GOAL_POSITION), 0x1234);
        // Response level 0: writes go unanswered, reads still answer.
        assert!(
            s.handle(3, inst::WRITE, &[addr::RESPONSE_LEVEL, 0]).is_none(),
            "in force at once"
        );
        assert!(s.handle(3, inst::WRITE, &[addr::ACCELERATION, 5]).is_none());
        assert!(s.handle(3, inst::READ, &[addr::ACCELERATION, 1]).is_some());
        // REG_WRITE waits for ACTION.
        s.handle(3, inst::REG_WRITE, &[addr::ACCELERATION, 9]);
        assert_eq!(s.register(addr::ACCELERATION), 5);
        s.handle(packet::BROADCAST_ID, inst::ACTION, &[]);
        assert_eq!(s.register(addr::ACCELERATION), 9);
    }

    #[test]
    fn a_held_overload_drops_to_the_protective_torque_then_unloads_and_reports_it() {
        let (mut s, _) = servo();
        let mut wall = InertiaPlant::new(1e6, 0.0, 0.0, 0.0);
        s.handle(3, inst::WRITE, &[addr::TORQUE_ENABLE, 1]).unwrap();
        s.handle(3, inst::WRITE, &[addr::GOAL_POSITION, 0x00, 0x0C])
            .unwrap();
        for _ in 0..1000 {
            s.tick(SimInstant::ZERO, &mut wall);
        }
        assert_eq!(s.status() & error::OVERLOAD, 0, "under the 2 s protection time");
        for _ in 0..1100 {
            s.tick(SimInstant::ZERO, &mut wall);
        }
        assert_ne!(s.status() & error::OVERLOAD, 0);
        assert!(!s.torque_enabled(), "overload is an unloading condition");
        let r = s.handle(3, inst::PING, &[]).unwrap();
        assert_eq!(r.error & error::OVERLOAD, error::OVERLOAD);
    }

    #[test]
    fn torque_enable_128_takes_the_present_position_as_the_middle() {
        let (mut s, mut p) = servo();
        p.q = 0.5;
        run(&mut s, &mut p, 0.002);
        s.handle(3, inst::WRITE, &[addr::TORQUE_ENABLE, 128]).unwrap();
        run(&mut s, &mut p, 0.002);
        assert_eq!(word(&s.table, addr::PRESENT_POSITION), 2048);
        assert!(!s.torque_enabled());
    }
}
