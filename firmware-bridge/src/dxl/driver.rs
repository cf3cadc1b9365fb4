//! Host driver for a line of Dynamixel X-series servos: check, configure, enable, and one sync
//! write plus one sync read per control tick, in joint units.
//!
//! Feedback is gathered through indirect addresses so one sync read returns, per servo, Hardware
//! Error Status, Present Current, Velocity, Position, Input Voltage and Temperature (16 bytes);
//! goals go out the same way (Goal Position and Goal Current, 6 bytes). The steady-state cycle
//! works in buffers sized at construction and does not allocate.

use std::time::Duration;

use super::models::{self, DxlModel};
use super::packet::{BROADCAST_ID, inst};
use super::table::{self, addr, status};
use super::transport::{DxlTransport, LinkError};

/// Control table bytes the feedback block maps, in order.
const FEEDBACK_MAP: [u16; 16] = [
    addr::HARDWARE_ERROR_STATUS,
    addr::PRESENT_CURRENT,
    addr::PRESENT_CURRENT + 1,
    addr::PRESENT_VELOCITY,
    addr::PRESENT_VELOCITY + 1,
    addr::PRESENT_VELOCITY + 2,
    addr::PRESENT_VELOCITY + 3,
    addr::PRESENT_POSITION,
    addr::PRESENT_POSITION + 1,
    addr::PRESENT_POSITION + 2,
    addr::PRESENT_POSITION + 3,
    addr::PRESENT_INPUT_VOLTAGE,
    addr::PRESENT_INPUT_VOLTAGE + 1,
    addr::PRESENT_TEMPERATURE,
    // Two spare bytes keep the block at 16; they map onto themselves.
    0,
    0,
];
/// Control table bytes the goal block maps: Goal Position, then Goal Current.
const GOAL_MAP: [u16; 6] = [
    addr::GOAL_POSITION,
    addr::GOAL_POSITION + 1,
    addr::GOAL_POSITION + 2,
    addr::GOAL_POSITION + 3,
    addr::GOAL_CURRENT,
    addr::GOAL_CURRENT + 1,
];
const FEEDBACK_SLOT: u16 = 1;
const GOAL_SLOT: u16 = 17;
const STATUS_OVERHEAD: usize = 11;
/// Times a single instruction is sent before a lost status counts as the servo's.
pub const EXCHANGE_TRIES: usize = 3;

/// Header, ID, length, instruction and CRC of an instruction packet.
const INSTRUCTION_OVERHEAD: usize = 10;

/// Wire time of one bus cycle of `servos` servos at `baud`: the goals' sync write, the sync
/// read's instruction and every servo's status, each servo waiting `return_delay` before it
/// answers.
pub fn cycle_wire_time(servos: usize, baud: u32, return_delay: Duration) -> Duration {
    let sync_write = INSTRUCTION_OVERHEAD + 4 + servos * (1 + GOAL_MAP.len());
    let sync_read = INSTRUCTION_OVERHEAD + 4 + servos;
    let statuses = servos * (STATUS_OVERHEAD + FEEDBACK_MAP.len());
    super::wire::WireTiming::new(baud).bytes_time(sync_write + sync_read + statuses)
        + return_delay * servos as u32
}

/// [`cycle_wire_time`] with the state read by a fast sync read: one status packet, and one
/// return delay (the first servo's), for every servo.
pub fn fast_cycle_wire_time(servos: usize, baud: u32, return_delay: Duration) -> Duration {
    let sync_write = INSTRUCTION_OVERHEAD + 4 + servos * (1 + GOAL_MAP.len());
    let sync_read = INSTRUCTION_OVERHEAD + 4 + servos;
    super::wire::WireTiming::new(baud).bytes_time(sync_write + sync_read + fast_status_len(servos))
        + return_delay
}

/// Bytes of a fast sync read's status packet for `servos` servos: the 8-byte prefix, and per
/// servo its error, ID, feedback and CRC (the last CRC is the packet's).
fn fast_status_len(servos: usize) -> usize {
    super::packet::FAST_STATUS_PREFIX + servos * (FEEDBACK_MAP.len() + super::packet::FAST_SEGMENT_OVERHEAD)
}

/// How a joint's servo is driven.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, schemars::JsonSchema, serde::Serialize,
)]
#[serde(rename_all = "snake_case")]
pub enum DxlMode {
    /// Position control within one turn (Operating Mode 3).
    #[default]
    Position,
    /// Multi-turn position control (4).
    ExtendedPosition,
    /// Position control whose output current is capped by Goal Current (5).
    CurrentBasedPosition,
    /// Current (torque) control (0).
    Current,
}

impl DxlMode {
    /// The Operating Mode value.
    pub const fn code(self) -> u8 {
        match self {
            Self::Position => 3,
            Self::ExtendedPosition => 4,
            Self::CurrentBasedPosition => 5,
            Self::Current => 0,
        }
    }

    /// Whether the mode reads Goal Current.
    pub const fn uses_current(self) -> bool {
        matches!(self, Self::CurrentBasedPosition | Self::Current)
    }
}

fn default_direction() -> f64 {
    1.0
}

fn default_zero_ticks() -> f64 {
    2048.0
}

/// One joint driven by a Dynamixel servo.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, schemars::JsonSchema, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct DxlJointConfig {
    /// Joint name (for messages and telemetry).
    pub name: String,
    /// Servo ID on its line.
    pub id: u8,
    /// Model name in the servo table, e.g. `XM430-W350`.
    pub model: String,
    /// +1 or -1: joint angle sign relative to the servo's positive direction.
    #[serde(default = "default_direction")]
    pub direction: f64,
    /// Present Position (ticks) at joint angle zero, Homing Offset included.
    #[serde(default = "default_zero_ticks")]
    pub zero_ticks: f64,
    /// Homing Offset to program (EEPROM, ticks): shifts Present Position so the joint's range
    /// stays clear of the encoder's 0/4095 wrap point. Calibration chooses it.
    #[serde(default)]
    pub homing_offset: i32,
    /// Operating mode.
    #[serde(default)]
    pub mode: DxlMode,
    /// Position P, I, D gains to set (the model's defaults when absent).
    #[serde(default)]
    pub position_gains: Option<[u16; 3]>,
    /// Current Limit to set, A (EEPROM; XM only).
    #[serde(default)]
    pub current_limit: Option<f64>,
    /// PWM Limit to set (EEPROM, 0–885 = 0–100 % duty): the torque cap of a servo that cannot
    /// sense its current, whose stall torque scales with the duty.
    #[serde(default)]
    pub pwm_limit: Option<u16>,
    /// The motor constants of a variant of `model` (another winding, gearing or supply): the
    /// driver turns load and current into torque with these. Its identity must be `model`'s.
    #[serde(skip)]
    pub constants: Option<DxlModel>,
}

impl DxlJointConfig {
    /// A joint in position mode, servo direction, zero at the centre of the range.
    pub fn new(name: &str, id: u8, model: &str) -> Self {
        Self {
            name: name.to_owned(),
            id,
            model: model.to_owned(),
            direction: 1.0,
            zero_ticks: 2048.0,
            homing_offset: 0,
            mode: DxlMode::Position,
            position_gains: None,
            current_limit: None,
            pwm_limit: None,
            constants: None,
        }
    }

    /// Joint angle, rad, of a Present Position.
    pub fn ticks_to_rad(&self, ticks: i32) -> f64 {
        self.direction * (f64::from(ticks) - self.zero_ticks) * models::rad_per_tick()
    }

    /// Goal Position of a joint angle, rad.
    pub fn rad_to_ticks(&self, q: f64) -> i32 {
        (self.zero_ticks + self.direction * q / models::rad_per_tick()).round() as i32
    }

    /// Joint velocity, rad/s, of a Present Velocity.
    pub fn velocity_to_rad_s(&self, units: i32) -> f64 {
        self.direction * f64::from(units) * models::rad_s_per_velocity_unit()
    }

    /// Joint-side current, A, of a Present/Goal Current value.
    pub fn current_to_amps(&self, units: i16) -> f64 {
        self.direction * f64::from(units) * models::CURRENT_UNIT_A
    }

    /// Goal Current of a joint-side current, A.
    pub fn amps_to_current(&self, amps: f64) -> i16 {
        (self.direction * amps / models::CURRENT_UNIT_A)
            .round()
            .clamp(-32768.0, 32767.0) as i16
    }
}

/// Line-wide driver settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DxlDriverOptions {
    /// Return Delay Time to program (EEPROM), or `None` to leave it.
    pub return_delay: Option<Duration>,
    /// Return Delay Time to expect when computing timeouts.
    pub expected_return_delay: Duration,
    /// Bus Watchdog to arm with torque (20 ms steps), or `None`.
    pub watchdog: Option<Duration>,
    /// Added to every reply deadline (host scheduling, adapter latency).
    pub reply_slack: Duration,
    /// The longest a sync read waits for its statuses (a bus cycle's share of its period), or
    /// `None`: as long as the wire, the return delays and the slack take.
    pub max_reply_wait: Option<Duration>,
    /// Read the state with Fast Sync Read (0x8A, X-series firmware 45 and later): one status
    /// packet for every servo instead of one each. A cycle whose fast read misses a servo is
    /// followed by [`FAST_READ_BACKOFF`] cycles of plain sync reads, so one silent servo costs
    /// only its own joint.
    pub fast_reads: bool,
}

/// Plain sync-read cycles after a fast read that missed a servo (a silent first servo loses the
/// whole fast packet: its header is that servo's to send).
pub const FAST_READ_BACKOFF: u32 = 50;

impl Default for DxlDriverOptions {
    fn default() -> Self {
        Self {
            return_delay: Some(Duration::ZERO),
            expected_return_delay: Duration::from_micros(500),
            watchdog: Some(Duration::from_millis(100)),
            reply_slack: Duration::from_millis(2),
            max_reply_wait: None,
            fast_reads: false,
        }
    }
}

/// A fault on one servo, as the driver saw it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DxlFault {
    /// No status packet before the deadline.
    #[error("servo {id}: no reply")]
    NoReply {
        /// Servo ID.
        id: u8,
    },
    /// Its status packet had a bad CRC.
    #[error("servo {id}: status packet with a bad CRC")]
    Crc {
        /// Servo ID.
        id: u8,
    },
    /// A status packet from another ID arrived in its place.
    #[error("servo {expected}: a status packet from ID {got} came in its place")]
    WrongId {
        /// Servo ID expected.
        expected: u8,
        /// ID received.
        got: u8,
    },
    /// It answered with an instruction error.
    #[error("servo {id}: {} (error byte {error:#04x})", status::name(*error))]
    Status {
        /// Servo ID.
        id: u8,
        /// Error byte.
        error: u8,
    },
    /// Its Hardware Error Status is non-zero.
    #[error("servo {id}: hardware error {bits:#04x} ({})", hardware_error_names(*bits))]
    Hardware {
        /// Servo ID.
        id: u8,
        /// Hardware Error Status bits.
        bits: u8,
    },
    /// Its status packet had the wrong size.
    #[error("servo {id}: malformed status packet")]
    Malformed {
        /// Servo ID.
        id: u8,
    },
}

impl DxlFault {
    /// The servo the fault concerns.
    pub fn id(&self) -> u8 {
        match *self {
            Self::NoReply { id }
            | Self::Crc { id }
            | Self::Status { id, .. }
            | Self::Hardware { id, .. }
            | Self::Malformed { id } => id,
            Self::WrongId { expected, .. } => expected,
        }
    }
}

/// Names of set Hardware Error Status bits.
pub fn hardware_error_names(bits: u8) -> &'static str {
    use table::hw;
    match bits {
        hw::VOLTAGE => "input voltage",
        hw::OVERHEAT => "overheating",
        hw::ENCODER => "motor encoder",
        hw::ELECTRICAL_SHOCK => "electrical shock",
        hw::OVERLOAD => "overload",
        0 => "none",
        _ => "several; see the bits",
    }
}

/// A servo whose scan result does not match its configuration.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ScanProblem {
    /// No answer to ping.
    Missing {
        /// Joint name.
        joint: String,
        /// Servo ID.
        id: u8,
    },
    /// Answered with another model number.
    WrongModel {
        /// Joint name.
        joint: String,
        /// Servo ID.
        id: u8,
        /// Configured model.
        expected: String,
        /// Model number it reported.
        found: u16,
    },
}

impl std::fmt::Display for ScanProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Missing { joint, id } => write!(f, "servo {id} ({joint}): no answer to ping"),
            Self::WrongModel {
                joint,
                id,
                expected,
                found,
            } => {
                let found_name =
                    models::find_by_number(*found).map_or("an unknown model", |m| m.name.as_str());
                write!(
                    f,
                    "servo {id} ({joint}): configured as {expected}, but it is model {found} ({found_name})"
                )
            }
        }
    }
}

/// Why a driver operation failed.
#[derive(Debug, thiserror::Error)]
pub enum DxlError {
    /// A servo fault during an operation that needs every servo.
    #[error(transparent)]
    Fault(#[from] DxlFault),
    /// Configured servos are missing or of another model; nothing was enabled.
    #[error("servo check failed, nothing enabled:\n  {}", .0.iter().map(ToString::to_string).collect::<Vec<_>>().join("\n  "))]
    Scan(Vec<ScanProblem>),
    /// The configuration is inconsistent.
    #[error("servo configuration: {0}")]
    Config(String),
    /// The line itself failed.
    #[error("serial line: {0}")]
    Link(LinkError),
}

/// A joint's goal for one tick.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DxlCommand {
    /// Joint angle, rad (position modes).
    pub q: f64,
    /// Joint current, A: the goal in current mode, the cap in current-based position mode.
    pub current: f64,
}

/// A joint's latest state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DxlFeedback<I> {
    /// Angle, rad.
    pub q: f64,
    /// Velocity, rad/s.
    pub qd: f64,
    /// Torque estimate, N·m (from current, or from Present Load on XL models).
    pub tau: f64,
    /// Current, A (models that sense current).
    pub current: Option<f64>,
    /// Hardware Error Status.
    pub hardware_error: u8,
    /// Input voltage, V.
    pub voltage: f64,
    /// Internal temperature, °C.
    pub temperature: f64,
    /// When the last good status packet arrived (`None`: never).
    pub received_at: Option<I>,
    /// Consecutive cycles without a good status packet (0: fresh).
    pub missed_cycles: u32,
    /// What went wrong in the last cycle, if anything.
    pub last_fault: Option<DxlFault>,
}

impl<I> DxlFeedback<I> {
    /// True when the last cycle brought no usable state.
    pub fn is_stale(&self) -> bool {
        self.missed_cycles > 0
    }
}

impl<I> Default for DxlFeedback<I> {
    fn default() -> Self {
        Self {
            q: 0.0,
            qd: 0.0,
            tau: 0.0,
            current: None,
            hardware_error: 0,
            voltage: 0.0,
            temperature: 0.0,
            received_at: None,
            missed_cycles: u32::MAX,
            last_fault: None,
        }
    }
}

/// What one sync read brought.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReadReport {
    /// Joints with fresh state.
    pub fresh: usize,
    /// Joints with stale state.
    pub stale: usize,
    /// The first fault seen (each joint's own is in its feedback).
    pub first_fault: Option<DxlFault>,
}

/// Driver counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DxlDriverStats {
    /// Sync read cycles.
    pub reads: u64,
    /// Sync writes.
    pub writes: u64,
    /// Faults seen.
    pub faults: u64,
    /// Statuses of an earlier sync read that arrived during a later one (skipped).
    pub late_statuses: u64,
    /// Cycles read with a fast sync read.
    pub fast_reads: u64,
}

/// The driver of one line of servos.
#[derive(Debug)]
pub struct DxlBusDriver<T: DxlTransport> {
    transport: T,
    joints: Vec<DxlJointConfig>,
    /// Each joint's model: the shipped one, or a variant's constants.
    models: Vec<DxlModel>,
    options: DxlDriverOptions,
    feedback: Vec<DxlFeedback<T::Instant>>,
    received: Vec<bool>,
    tx: Vec<u8>,
    /// When the statuses of the sync read last sent are due.
    state_deadline: Option<T::Instant>,
    /// The read last sent was a fast sync read.
    fast_pending: bool,
    /// A fast read's feedback bytes and outcome per joint, before they are decoded.
    fast_data: Vec<u8>,
    fast_outcomes: Vec<Result<(), DxlFault>>,
    /// Plain sync reads to go before the next fast one.
    fast_backoff: u32,
    stats: DxlDriverStats,
}

impl<T: DxlTransport> DxlBusDriver<T> {
    /// A driver for `joints` on `transport`. Checks the configuration, not the servos.
    pub fn new(
        transport: T,
        joints: Vec<DxlJointConfig>,
        options: DxlDriverOptions,
    ) -> Result<Self, DxlError> {
        let mut resolved = Vec::with_capacity(joints.len());
        for (i, j) in joints.iter().enumerate() {
            let shipped = models::find(&j.model).ok_or_else(|| {
                let known: Vec<_> = models::builtin().iter().map(|m| m.name.as_str()).collect();
                DxlError::Config(format!(
                    "joint {:?}: model {:?} is not one of {}",
                    j.name,
                    j.model,
                    known.join(", ")
                ))
            })?;
            let model = match &j.constants {
                Some(c)
                    if c.model_number != shipped.model_number
                        || c.current_sensing != shipped.current_sensing =>
                {
                    return Err(DxlError::Config(format!(
                        "joint {:?}: the constants of {:?} are not a variant of {} (model number {}, current sensing {})",
                        j.name, c.name, shipped.name, shipped.model_number, shipped.current_sensing
                    )));
                }
                Some(c) => c,
                None => shipped,
            };
            if j.id > 252 {
                return Err(DxlError::Config(format!(
                    "joint {:?}: id {} is above 252",
                    j.name, j.id
                )));
            }
            if let Some(other) = joints[..i].iter().find(|o| o.id == j.id) {
                return Err(DxlError::Config(format!(
                    "joints {:?} and {:?} share id {}",
                    other.name, j.name, j.id
                )));
            }
            if j.direction.abs() != 1.0 {
                return Err(DxlError::Config(format!(
                    "joint {:?}: direction = {} (must be 1 or -1)",
                    j.name, j.direction
                )));
            }
            if !j.zero_ticks.is_finite() {
                return Err(DxlError::Config(format!(
                    "joint {:?}: zero_ticks is not finite",
                    j.name
                )));
            }
            if j.mode.uses_current() && !model.current_sensing {
                return Err(DxlError::Config(format!(
                    "joint {:?}: {} has no current sensing, so mode {:?} is not available",
                    j.name, model.name, j.mode
                )));
            }
            if let Some(limit) = j.current_limit {
                let max = f64::from(model.current_limit) * models::CURRENT_UNIT_A;
                if !(model.current_sensing && limit > 0.0 && limit <= max) {
                    return Err(DxlError::Config(format!(
                        "joint {:?}: current_limit = {limit} A (must be in (0, {max:.3}] on a current-sensing model)",
                        j.name
                    )));
                }
            }
            if let Some(limit) = j.pwm_limit
                && !(1..=model.pwm_limit).contains(&limit)
            {
                return Err(DxlError::Config(format!(
                    "joint {:?}: pwm_limit = {limit} (must be in [1, {}])",
                    j.name, model.pwm_limit
                )));
            }
            resolved.push(model.clone());
        }
        let n = joints.len();
        Ok(Self {
            transport,
            models: resolved,
            options,
            feedback: vec![DxlFeedback::default(); n],
            received: vec![false; n],
            tx: Vec::with_capacity(8 + n * (1 + GOAL_MAP.len()) + 16),
            joints,
            state_deadline: None,
            fast_pending: false,
            fast_data: vec![0; n * FEEDBACK_MAP.len()],
            fast_outcomes: vec![Ok(()); n],
            fast_backoff: 0,
            stats: DxlDriverStats::default(),
        })
    }

    /// The joints, in configuration order.
    pub fn joints(&self) -> &[DxlJointConfig] {
        &self.joints
    }

    /// Latest state per joint.
    pub fn feedback(&self) -> &[DxlFeedback<T::Instant>] {
        &self.feedback
    }

    /// Counters.
    pub fn stats(&self) -> DxlDriverStats {
        self.stats
    }

    /// The transport.
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// The transport, mutably (fault injection, recording).
    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.transport
    }

    fn deadline(&self, request: usize, reply: usize, servos: usize) -> T::Instant {
        let wire = super::wire::WireTiming::new(self.transport.baud());
        let budget = wire.bytes_time(request + reply)
            + self.options.expected_return_delay * servos.max(1) as u32
            + self.options.reply_slack;
        self.transport.now() + budget
    }

    /// Pings a servo: its model number and firmware version.
    pub fn ping(&mut self, id: u8) -> Result<(u16, u8), DxlError> {
        let mut out = [0u8; 3];
        self.exchange(id, inst::PING, &[], &mut out)?;
        Ok((u16::from_le_bytes([out[0], out[1]]), out[2]))
    }

    /// Reads `out.len()` bytes from `address` of servo `id`.
    pub fn read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), DxlError> {
        let [a0, a1] = address.to_le_bytes();
        let [l0, l1] = (out.len() as u16).to_le_bytes();
        self.exchange(id, inst::READ, &[a0, a1, l0, l1], out)
    }

    /// Writes `data` at `address` of servo `id` and waits for its acknowledgement.
    pub fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<(), DxlError> {
        let mut params = [0u8; 64];
        let n = data.len() + 2;
        if n > params.len() {
            return Err(DxlError::Config(format!(
                "write of {} bytes is too long",
                data.len()
            )));
        }
        params[..2].copy_from_slice(&address.to_le_bytes());
        params[2..n].copy_from_slice(data);
        self.exchange(id, inst::WRITE, &params[..n], &mut [])
    }

    /// Sends an instruction, checks the status packet and copies its parameters into `out`.
    /// One instruction and its status, asked again (up to [`EXCHANGE_TRIES`] times) when the
    /// status is lost or garbled: a late or damaged reply on a busy host is not a missing servo.
    /// Every instruction sent this way (ping, read, write of a value, reboot) may be repeated.
    fn exchange(&mut self, id: u8, instruction: u8, params: &[u8], out: &mut [u8]) -> Result<(), DxlError> {
        let mut tries = 1;
        loop {
            match self.exchange_once(id, instruction, params, out) {
                Err(DxlError::Fault(
                    DxlFault::NoReply { .. } | DxlFault::Crc { .. } | DxlFault::Malformed { .. },
                )) if tries < EXCHANGE_TRIES => tries += 1,
                r => return r,
            }
        }
    }

    fn exchange_once(
        &mut self,
        id: u8,
        instruction: u8,
        params: &[u8],
        out: &mut [u8],
    ) -> Result<(), DxlError> {
        self.transport
            .send(id, instruction, params)
            .map_err(DxlError::Link)?;
        let deadline = self.deadline(10 + params.len(), STATUS_OVERHEAD + out.len(), 1);
        let mut status = self.transport.recv_status(deadline);
        // Another servo's status is the late answer to an earlier instruction (two servos never
        // answer for one ID): skip it and keep waiting for this one's.
        while matches!(&status, Ok(s) if s.id != id) {
            self.stats.late_statuses += 1;
            status = self.transport.recv_status(deadline);
        }
        let fault = match status {
            Ok(s) if s.error & 0x7F != 0 => DxlFault::Status { id, error: s.error },
            Ok(s) if s.params.len() != out.len() => DxlFault::Malformed { id },
            Ok(s) => {
                out.copy_from_slice(s.params);
                return Ok(());
            }
            Err(LinkError::Timeout) => DxlFault::NoReply { id },
            Err(LinkError::Crc) => DxlFault::Crc { id },
            Err(LinkError::ServoError(error)) => DxlFault::Status { id, error },
            Err(LinkError::Malformed) => DxlFault::Malformed { id },
            Err(e @ LinkError::Io(_)) => return Err(DxlError::Link(e)),
        };
        self.stats.faults += 1;
        Err(fault.into())
    }

    /// Pings every configured servo and checks its model. Nothing is written.
    pub fn check_servos(&mut self) -> Result<(), DxlError> {
        let mut problems = Vec::new();
        for i in 0..self.joints.len() {
            let (id, number_wanted) = (self.joints[i].id, self.models[i].model_number);
            match self.ping(id) {
                Ok((number, _)) if number == number_wanted => {}
                Ok((found, _)) => problems.push(ScanProblem::WrongModel {
                    joint: self.joints[i].name.clone(),
                    id,
                    expected: self.models[i].name.clone(),
                    found,
                }),
                Err(DxlError::Link(e)) => return Err(DxlError::Link(e)),
                Err(_) => problems.push(ScanProblem::Missing {
                    joint: self.joints[i].name.clone(),
                    id,
                }),
            }
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(DxlError::Scan(problems))
        }
    }

    /// Checks the servos, then with torque off programs operating mode, gains, limits, return
    /// delay and the indirect addresses of the feedback and goal blocks.
    pub fn configure(&mut self) -> Result<(), DxlError> {
        self.check_servos()?;
        self.disable()?;
        for i in 0..self.joints.len() {
            self.configure_joint(i)?;
        }
        Ok(())
    }

    fn configure_joint(&mut self, i: usize) -> Result<(), DxlError> {
        let j = self.joints[i].clone();
        let model = self.models[i].clone();
        let id = j.id;
        self.write(id, addr::STATUS_RETURN_LEVEL, &[2])?;
        if let Some(delay) = self.options.return_delay {
            let units = (delay.as_micros() / 2).min(254) as u8;
            self.write(id, addr::RETURN_DELAY_TIME, &[units])?;
        }
        // Homing Offset before the mode: writing the mode restarts the turn count from the
        // encoder's single-turn reading, now shifted by the offset.
        self.write(id, addr::HOMING_OFFSET, &j.homing_offset.to_le_bytes())?;
        self.write(id, addr::OPERATING_MODE, &[j.mode.code()])?;
        if let Some(limit) = j.current_limit {
            let units = (limit / models::CURRENT_UNIT_A).round() as u16;
            self.write(id, addr::CURRENT_LIMIT, &units.to_le_bytes())?;
        }
        if let Some(limit) = j.pwm_limit {
            self.write(id, addr::PWM_LIMIT, &limit.to_le_bytes())?;
        }
        let [p, ii, d] = j.position_gains.unwrap_or(model.position_gains);
        let mut gains = [0u8; 6];
        gains[..2].copy_from_slice(&d.to_le_bytes());
        gains[2..4].copy_from_slice(&ii.to_le_bytes());
        gains[4..].copy_from_slice(&p.to_le_bytes());
        self.write(id, addr::POSITION_D_GAIN, &gains)?;
        self.map_indirect(i)
    }

    fn map_indirect(&mut self, i: usize) -> Result<(), DxlError> {
        let id = self.joints[i].id;
        let current = self.models[i].current_sensing;
        let mut block = [0u8; 2 * (FEEDBACK_MAP.len() + GOAL_MAP.len())];
        for (k, &target) in FEEDBACK_MAP.iter().chain(&GOAL_MAP).enumerate() {
            let slot = FEEDBACK_SLOT + k as u16;
            let own_data = addr::INDIRECT_DATA_1 + slot - 1;
            // Spare bytes, and Goal Current on models without it, point at their own data byte.
            let target = if target == 0
                || (!current && (addr::GOAL_CURRENT..addr::GOAL_CURRENT + 2).contains(&target))
            {
                own_data
            } else {
                target
            };
            block[2 * k..2 * k + 2].copy_from_slice(&target.to_le_bytes());
        }
        debug_assert_eq!(GOAL_SLOT, FEEDBACK_SLOT + FEEDBACK_MAP.len() as u16);
        self.write(id, addr::INDIRECT_ADDRESS_1, &block)
    }

    fn broadcast_byte(&mut self, address: u16, value: u8) -> Result<(), DxlError> {
        self.tx.clear();
        self.tx.extend_from_slice(&address.to_le_bytes());
        self.tx.extend_from_slice(&1u16.to_le_bytes());
        for j in &self.joints {
            self.tx.extend_from_slice(&[j.id, value]);
        }
        self.transport
            .send(BROADCAST_ID, inst::SYNC_WRITE, &self.tx)
            .map_err(DxlError::Link)
    }

    /// Turns torque on for every joint (holding where each is) and arms the Bus Watchdog.
    pub fn enable(&mut self) -> Result<(), DxlError> {
        if let Some(wd) = self.options.watchdog {
            let units = (wd.as_millis() / 20).clamp(1, 127) as u8;
            self.broadcast_byte(addr::BUS_WATCHDOG, units)?;
        }
        self.broadcast_byte(addr::TORQUE_ENABLE, 1)?;
        // Confirm: a sync write has no answer, so read torque back from each servo.
        for i in 0..self.joints.len() {
            let id = self.joints[i].id;
            let mut on = [0u8];
            self.read(id, addr::TORQUE_ENABLE, &mut on)?;
            if on[0] != 1 {
                let mut hw = [0u8];
                self.read(id, addr::HARDWARE_ERROR_STATUS, &mut hw)?;
                return Err(DxlFault::Hardware { id, bits: hw[0] }.into());
            }
        }
        Ok(())
    }

    /// Turns torque off on every joint (one broadcast sync write, no answer awaited).
    pub fn disable(&mut self) -> Result<(), DxlError> {
        self.broadcast_byte(addr::TORQUE_ENABLE, 0)?;
        // A fired watchdog blocks goal writes until cleared.
        self.broadcast_byte(addr::BUS_WATCHDOG, 0)
    }

    /// Reboots a servo (clearing a shutdown), waits for it to answer again and restores the
    /// RAM settings a reboot loses. Torque stays off.
    pub fn recover(&mut self, joint: usize, boot_timeout: Duration) -> Result<(), DxlError> {
        let id = self.joints[joint].id;
        self.exchange(id, inst::REBOOT, &[], &mut [])?;
        let give_up = self.transport.now() + boot_timeout;
        loop {
            match self.ping(id) {
                Ok(_) => break,
                Err(DxlError::Fault(_)) if self.transport.now() < give_up => {}
                Err(e) => return Err(e),
            }
        }
        self.configure_joint(joint)
    }

    /// One sync write of every joint's Position D, I and P gains (`[P, I, D]` per joint, the
    /// control table's units), e.g. when the loop changes a joint's stiffness or damping.
    pub fn write_gains(&mut self, gains: &[[u16; 3]]) -> Result<(), DxlError> {
        if gains.len() != self.joints.len() {
            return Err(DxlError::Config(format!(
                "{} gain sets for {} joints",
                gains.len(),
                self.joints.len()
            )));
        }
        if let Some((i, _)) = gains
            .iter()
            .enumerate()
            .find(|(_, g)| g.iter().any(|&v| v > 16383))
        {
            return Err(DxlError::Config(format!(
                "joint {:?}: gains {:?} beyond the servo's 0..=16383",
                self.joints[i].name, gains[i]
            )));
        }
        self.sync_write(addr::POSITION_D_GAIN, 6, |k, _, tx| {
            let [p, i, d] = gains[k];
            for v in [d, i, p] {
                tx.extend_from_slice(&v.to_le_bytes());
            }
        })
    }

    /// One sync write of `len` bytes at `address` to every joint, `fill` appending each joint's
    /// bytes (it gets the joint's index and configuration).
    fn sync_write(
        &mut self,
        address: u16,
        len: u16,
        mut fill: impl FnMut(usize, &DxlJointConfig, &mut Vec<u8>),
    ) -> Result<(), DxlError> {
        self.tx.clear();
        self.tx.extend_from_slice(&address.to_le_bytes());
        self.tx.extend_from_slice(&len.to_le_bytes());
        for (k, j) in self.joints.iter().enumerate() {
            self.tx.push(j.id);
            fill(k, j, &mut self.tx);
        }
        self.stats.writes += 1;
        self.transport
            .send(BROADCAST_ID, inst::SYNC_WRITE, &self.tx)
            .map_err(DxlError::Link)
    }

    /// One sync write of every joint's goal.
    ///
    /// Commands with a non-finite field are refused before anything is sent.
    pub fn write_goals(&mut self, commands: &[DxlCommand]) -> Result<(), DxlError> {
        if commands.len() != self.joints.len() {
            return Err(DxlError::Config(format!(
                "{} commands for {} joints",
                commands.len(),
                self.joints.len()
            )));
        }
        if let Some((i, _)) = commands
            .iter()
            .enumerate()
            .find(|(_, c)| !(c.q.is_finite() && c.current.is_finite()))
        {
            return Err(DxlError::Config(format!(
                "joint {:?}: non-finite command refused",
                self.joints[i].name
            )));
        }
        let goal = addr::INDIRECT_DATA_1 + GOAL_SLOT - 1;
        self.sync_write(goal, GOAL_MAP.len() as u16, |k, j, tx| {
            tx.extend_from_slice(&j.rad_to_ticks(commands[k].q).to_le_bytes());
            tx.extend_from_slice(&j.amps_to_current(commands[k].current).to_le_bytes());
        })
    }

    /// One sync read of every joint's state. Faults are per joint (see [`DxlFeedback`]); only a
    /// failing line is an error.
    pub fn read_state(&mut self) -> Result<ReadReport, DxlError> {
        self.request_state()?;
        self.collect_state()
    }

    /// The first half of a sync read: sends the instruction. The statuses are due by a deadline
    /// from the bytes on the wire, the return delays and the slack (capped by
    /// [`DxlDriverOptions::max_reply_wait`]); [`Self::collect_state`] takes them. Between the two,
    /// other buses can be served.
    pub fn request_state(&mut self) -> Result<(), DxlError> {
        let n = self.joints.len();
        self.tx.clear();
        self.tx
            .extend_from_slice(&(addr::INDIRECT_DATA_1 + FEEDBACK_SLOT - 1).to_le_bytes());
        self.tx
            .extend_from_slice(&(FEEDBACK_MAP.len() as u16).to_le_bytes());
        for j in &self.joints {
            self.tx.push(j.id);
        }
        let fast = self.options.fast_reads && self.fast_backoff == 0;
        self.fast_backoff = self.fast_backoff.saturating_sub(1);
        let instruction = if fast {
            inst::FAST_SYNC_READ
        } else {
            inst::SYNC_READ
        };
        self.transport
            .send(BROADCAST_ID, instruction, &self.tx)
            .map_err(DxlError::Link)?;
        self.stats.reads += 1;
        let reply = if fast {
            fast_status_len(n)
        } else {
            n * (STATUS_OVERHEAD + FEEDBACK_MAP.len())
        };
        let mut deadline = self.deadline(10 + self.tx.len(), reply, n);
        if let Some(cap) = self.options.max_reply_wait {
            deadline = deadline.min(self.transport.now() + cap);
        }
        self.state_deadline = Some(deadline);
        self.fast_pending = fast;
        Ok(())
    }

    /// A fast sync read's one status packet, servo by servo: each segment's ID must be the next
    /// listed servo's (else that servo did not answer and the next one's segment starts there),
    /// and its CRC that of every byte on the wire before it.
    fn collect_fast(&mut self, deadline: T::Instant, report: &mut ReadReport) -> Result<(), DxlError> {
        let n = self.joints.len();
        let width = FEEDBACK_MAP.len();
        let seg = width + super::packet::FAST_SEGMENT_OVERHEAD;
        self.stats.fast_reads += 1;
        // Parse into buffers made once (the packet is borrowed from the transport meanwhile).
        let (joints, data, outcomes) = (&self.joints, &mut self.fast_data, &mut self.fast_outcomes);
        let bytes = match self.transport.recv_raw(fast_status_len(n), deadline) {
            Ok(b) => b,
            Err(LinkError::Io(e)) => return Err(DxlError::Link(LinkError::Io(e))),
            Err(_) => &[][..],
        };
        let head_ok = bytes.len() >= super::packet::FAST_STATUS_PREFIX
            && bytes[4] == BROADCAST_ID
            && bytes[7] == super::packet::STATUS;
        let mut at = super::packet::FAST_STATUS_PREFIX;
        let mut crc = if head_ok {
            super::packet::crc16(0, &bytes[..at])
        } else {
            0
        };
        for (k, (j, outcome)) in joints.iter().zip(outcomes.iter_mut()).enumerate() {
            let id = j.id;
            *outcome = if !head_ok || at + seg > bytes.len() || bytes[at + 1] != id {
                // No segment, or not this servo's: it stayed silent, the slot is the next one's.
                Err(DxlFault::NoReply { id })
            } else {
                let data_end = at + 2 + width;
                let computed = super::packet::crc16(crc, &bytes[at..data_end]);
                let received = u16::from_le_bytes([bytes[data_end], bytes[data_end + 1]]);
                crc = super::packet::crc16(crc, &bytes[at..at + seg]);
                let error = bytes[at];
                data[k * width..(k + 1) * width].copy_from_slice(&bytes[at + 2..data_end]);
                at += seg;
                if computed != received {
                    Err(DxlFault::Crc { id })
                } else if error & 0x7F != 0 {
                    Err(DxlFault::Status { id, error })
                } else {
                    Ok(())
                }
            };
        }
        let now = self.transport.now();
        let mut missed_any = false;
        for k in 0..n {
            match self.fast_outcomes[k] {
                Ok(()) => {
                    let fb = decode_feedback(
                        &self.joints[k],
                        &self.models[k],
                        &self.fast_data[k * width..(k + 1) * width],
                    );
                    self.feedback[k] = DxlFeedback {
                        received_at: Some(now),
                        ..fb
                    };
                    let bits = self.feedback[k].hardware_error;
                    if bits != 0 {
                        let f = DxlFault::Hardware {
                            id: self.joints[k].id,
                            bits,
                        };
                        self.feedback[k].last_fault = Some(f);
                        report.first_fault.get_or_insert(f);
                        self.stats.faults += 1;
                    }
                }
                Err(f) => {
                    missed_any = true;
                    self.mark_missed(k, f, report);
                }
            }
        }
        if missed_any {
            self.fast_backoff = FAST_READ_BACKOFF;
        }
        Ok(())
    }

    /// The second half of a sync read: takes the statuses until all are in or the deadline set
    /// by [`Self::request_state`] passes (at once, if it has: only what has arrived).
    pub fn collect_state(&mut self) -> Result<ReadReport, DxlError> {
        let n = self.joints.len();
        let Some(deadline) = self.state_deadline.take() else {
            return Err(DxlError::Config(
                "statuses collected before a sync read was sent".into(),
            ));
        };
        self.received.fill(false);
        for fb in &mut self.feedback {
            fb.last_fault = None;
        }
        let mut report = ReadReport::default();
        if std::mem::take(&mut self.fast_pending) {
            self.collect_fast(deadline, &mut report)?;
            return Ok(self.tally(report));
        }
        let mut outstanding = n;
        while outstanding > 0 {
            // Replies come in list order: a packet that cannot name its sender belongs to the
            // first joint still waiting.
            let next = self
                .received
                .iter()
                .position(|r| !r)
                .expect("a joint is outstanding");
            let (index, fault, fresh) = match self.transport.recv_status(deadline) {
                Ok(s) => match self.joints.iter().position(|j| j.id == s.id) {
                    Some(i) if self.received[i] => {
                        // A second status from a servo already heard: the tail of an earlier
                        // sync read that missed its deadline. Not this cycle's, and no fault of
                        // the servo still awaited.
                        self.stats.late_statuses += 1;
                        continue;
                    }
                    None => (
                        next,
                        Some(DxlFault::WrongId {
                            expected: self.joints[next].id,
                            got: s.id,
                        }),
                        false,
                    ),
                    Some(i) if s.error & 0x7F != 0 => (
                        i,
                        Some(DxlFault::Status {
                            id: s.id,
                            error: s.error,
                        }),
                        false,
                    ),
                    Some(i) if s.params.len() != FEEDBACK_MAP.len() => {
                        (i, Some(DxlFault::Malformed { id: s.id }), false)
                    }
                    Some(i) => {
                        self.feedback[i] = decode_feedback(&self.joints[i], &self.models[i], s.params);
                        let bits = self.feedback[i].hardware_error;
                        (
                            i,
                            (bits != 0).then_some(DxlFault::Hardware { id: s.id, bits }),
                            true,
                        )
                    }
                },
                Err(LinkError::Timeout) => {
                    for i in 0..n {
                        if !self.received[i] {
                            self.received[i] = true;
                            self.mark_missed(
                                i,
                                DxlFault::NoReply {
                                    id: self.joints[i].id,
                                },
                                &mut report,
                            );
                        }
                    }
                    break;
                }
                Err(LinkError::Crc) => (
                    next,
                    Some(DxlFault::Crc {
                        id: self.joints[next].id,
                    }),
                    false,
                ),
                Err(LinkError::ServoError(error)) => (
                    next,
                    Some(DxlFault::Status {
                        id: self.joints[next].id,
                        error,
                    }),
                    false,
                ),
                Err(LinkError::Malformed) => (
                    next,
                    Some(DxlFault::Malformed {
                        id: self.joints[next].id,
                    }),
                    false,
                ),
                Err(e @ LinkError::Io(_)) => return Err(DxlError::Link(e)),
            };
            if fresh {
                self.feedback[index].received_at = Some(self.transport.now());
            }
            self.received[index] = true;
            outstanding -= 1;
            match fault {
                // Hardware errors come with valid state: fresh, but reported.
                Some(f @ DxlFault::Hardware { .. }) => {
                    self.feedback[index].last_fault = Some(f);
                    report.first_fault.get_or_insert(f);
                    self.stats.faults += 1;
                }
                Some(f) => self.mark_missed(index, f, &mut report),
                None => {}
            }
        }
        Ok(self.tally(report))
    }

    /// Counts fresh and stale joints into `report`.
    fn tally(&self, mut report: ReadReport) -> ReadReport {
        for fb in &self.feedback {
            if fb.is_stale() {
                report.stale += 1;
            } else {
                report.fresh += 1;
            }
        }
        report
    }

    fn mark_missed(&mut self, i: usize, fault: DxlFault, report: &mut ReadReport) {
        let fb = &mut self.feedback[i];
        fb.missed_cycles = fb.missed_cycles.saturating_add(1).max(1);
        if fb.received_at.is_none() {
            fb.missed_cycles = u32::MAX;
        }
        fb.last_fault = Some(fault);
        report.first_fault.get_or_insert(fault);
        self.stats.faults += 1;
    }

    /// Writes goals, then reads state: one control tick's bus traffic.
    pub fn cycle(&mut self, commands: &[DxlCommand]) -> Result<ReadReport, DxlError> {
        self.write_goals(commands)?;
        self.read_state()
    }
}

fn decode_feedback<I>(joint: &DxlJointConfig, model: &DxlModel, b: &[u8]) -> DxlFeedback<I> {
    let raw_current = i16::from_le_bytes([b[1], b[2]]);
    let velocity = i32::from_le_bytes([b[3], b[4], b[5], b[6]]);
    let position = i32::from_le_bytes([b[7], b[8], b[9], b[10]]);
    let voltage = f64::from(u16::from_le_bytes([b[11], b[12]])) * 0.1;
    let (current, tau) = if model.current_sensing {
        let amps = joint.current_to_amps(raw_current);
        (Some(amps), amps * model.torque_constant())
    } else {
        // Present Load, 0.1 % of stall torque.
        (
            None,
            joint.direction * f64::from(raw_current) / 1000.0 * model.stall_torque,
        )
    };
    DxlFeedback {
        q: joint.ticks_to_rad(position),
        qd: joint.velocity_to_rad_s(velocity),
        tau,
        current,
        hardware_error: b[0],
        voltage,
        temperature: f64::from(b[13]),
        received_at: None,
        missed_cycles: 0,
        last_fault: None,
    }
}

/// A servo that answered a scan.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScanHit {
    /// Its ID.
    pub id: u8,
    /// Model number from ping.
    pub model_number: u16,
    /// Firmware version from ping.
    pub firmware: u8,
    /// Hardware Error Status (`None`: its read came back late or garbled).
    pub hardware_error: Option<u8>,
    /// Present Position, ticks (`None`: not read).
    pub position: Option<i32>,
    /// Present Temperature, °C (`None`: not read).
    pub temperature: Option<u8>,
}

/// Pings per ID before a scan calls it missing.
pub const SCAN_TRIES: usize = 3;

/// Pings every ID in `ids` (each up to [`SCAN_TRIES`] times) and reads the state of those that
/// answer. Writes nothing.
pub fn scan<T: DxlTransport>(
    transport: &mut T,
    ids: std::ops::RangeInclusive<u8>,
    timeout: Duration,
) -> Result<Vec<ScanHit>, LinkError> {
    let mut hits = Vec::new();
    for id in ids {
        let mut ask = |instruction: u8, params: &[u8], want: usize| -> Result<Option<[u8; 4]>, LinkError> {
            transport.send(id, instruction, params)?;
            match transport.recv_status(transport.now() + timeout) {
                Ok(s) if s.id == id && s.params.len() == want => {
                    let mut out = [0u8; 4];
                    out[..want].copy_from_slice(s.params);
                    Ok(Some(out))
                }
                Ok(_)
                | Err(
                    LinkError::Timeout | LinkError::Crc | LinkError::Malformed | LinkError::ServoError(_),
                ) => Ok(None),
                Err(e) => Err(e),
            }
        };
        // A silent ID is asked again before it counts as missing: one late or lost reply (a
        // busy USB adapter or pseudo-terminal) is not an absent servo.
        let mut ping = None;
        for _ in 0..SCAN_TRIES {
            ping = ask(inst::PING, &[], 3)?;
            if ping.is_some() {
                break;
            }
        }
        let Some(ping) = ping else {
            continue;
        };
        let read = |a: u16, n: u16| {
            let [a0, a1] = a.to_le_bytes();
            let [n0, n1] = n.to_le_bytes();
            [a0, a1, n0, n1]
        };
        // A reading that comes back late or garbled is unknown, not zero.
        let hw = ask(inst::READ, &read(addr::HARDWARE_ERROR_STATUS, 1), 1)?;
        let pos = ask(inst::READ, &read(addr::PRESENT_POSITION, 4), 4)?;
        let temp = ask(inst::READ, &read(addr::PRESENT_TEMPERATURE, 1), 1)?;
        hits.push(ScanHit {
            id,
            model_number: u16::from_le_bytes([ping[0], ping[1]]),
            firmware: ping[2],
            hardware_error: hw.map(|b| b[0]),
            position: pos.map(i32::from_le_bytes),
            temperature: temp.map(|b| b[0]),
        });
    }
    Ok(hits)
}
