//! Host driver for Feetech STS servos on one half-duplex line.
//!
//! Set-up ([`FeetechBusDriver::configure`]): every configured ID is pinged and its model checked
//! before anything is written; with the output off and the EPROM unlocked it programs position
//! mode, the homing offset and the position gains, then locks the EPROM again. Per tick: one
//! sync write of the goal positions (sign-magnitude) and one sync read of the state block
//! (position, speed, load, voltage, temperature, status, current) that each servo answers in its
//! turn; a servo whose answer does not come before the deadline keeps its last state, marked
//! stale with its age. The error byte of a status carries the servo's protections (voltage,
//! angle sensor, overheat, overcurrent, overload): the state is fresh, the fault reported.
//! Buffers are made at construction: a cycle does not allocate.

use std::time::Duration;

use super::models::FeetechModel;
use super::packet::{BROADCAST_ID, Feetech, from_sign_magnitude, inst, to_sign_magnitude};
use super::table::{self, addr};
use crate::half_duplex::{LinkError, LockstepServoPort, SerialServoPort, ServoTransport};
use crate::time::BusInstant;

/// A half-duplex Feetech line as the host driver sees it.
pub trait FeetechTransport: ServoTransport<Codec = Feetech> {}

impl<T: ServoTransport<Codec = Feetech>> FeetechTransport for T {}

/// A serial device speaking Feetech's protocol.
pub type SerialFeetechPort = SerialServoPort<Feetech>;

/// The host's end of a Feetech line of a simulated world.
pub type LockstepFeetechPort<W> = LockstepServoPort<W, Feetech>;

impl SerialServoPort<Feetech> {
    /// Opens `path` at `baud` (8N1, raw).
    pub fn open(path: &str, baud: u32) -> std::io::Result<Self> {
        Ok(Self::from_port(serial2::SerialPort::open(path, baud)?, baud))
    }
}

/// Wire time of one tick on a line of `servos` STS servos at `baud`: the goals' sync write, the
/// state's sync read and every servo's status packet, back to back (return delay 0).
pub fn cycle_wire_time(servos: usize, baud: u32) -> Duration {
    let write = 8 + servos * 3;
    let read = 8 + servos;
    let answers = servos * (STATUS_OVERHEAD + usize::from(table::STATE_LEN));
    crate::half_duplex::WireTiming::new(baud).bytes_time(write + read + answers)
}

/// One joint on an STS servo.
#[derive(Debug, Clone, PartialEq)]
pub struct FeetechJointConfig {
    /// Joint name, for errors and logs.
    pub name: String,
    /// Servo ID on its line.
    pub id: u8,
    /// Model.
    pub model: FeetechModel,
    /// +1 or −1: joint angle sign relative to the servo's positive direction.
    pub direction: f64,
    /// Present Position (ticks) at joint angle zero, homing offset included.
    pub zero_ticks: f64,
    /// How far the servo's reading is shifted, ticks (±2047): Present Position = encoder +
    /// this, as a Dynamixel's Homing Offset shifts it, so calibration treats both alike. Keeps
    /// the joint's range clear of the encoder's 0/4095 wrap. (The servo's own register subtracts:
    /// it is programmed with the opposite sign.)
    pub homing_offset: i32,
    /// Position P and D coefficients (EPROM addresses 21, 22); the factory's 32, 32 when absent.
    pub gains: Option<[u8; 2]>,
    /// Torque Limit to set, 0.1 % of full output (SRAM).
    pub torque_limit: Option<u16>,
}

impl FeetechJointConfig {
    /// A joint in the servo's direction, zero at the middle of the range.
    pub fn new(name: &str, id: u8, model: &FeetechModel) -> Self {
        Self {
            name: name.to_owned(),
            id,
            model: model.clone(),
            direction: 1.0,
            zero_ticks: 2048.0,
            homing_offset: 0,
            gains: None,
            torque_limit: None,
        }
    }

    /// Joint angle (rad) of a Present Position.
    pub fn rad_of(&self, ticks: i32) -> f64 {
        self.direction * (f64::from(ticks) - self.zero_ticks) * table::rad_per_tick()
    }

    /// Goal Position (ticks) of a joint angle, within one turn.
    pub fn ticks_of(&self, q: f64) -> i32 {
        (self.zero_ticks + self.direction * q / table::rad_per_tick())
            .round()
            .clamp(0.0, f64::from(table::TICKS_PER_TURN - 1)) as i32
    }
}

/// The position P and D coefficients that give about stiffness `kp` (N·m/rad) and damping `kd`
/// (N·m·s/rad) at nominal voltage, by the loop law of [`table::P_DUTY_PER_TICK`].
pub fn gains_for(kp: f64, kd: f64, model: &FeetechModel) -> [u8; 2] {
    let per_tick = table::rad_per_tick();
    let p = kp * per_tick / (table::P_DUTY_PER_TICK * model.stall_torque);
    let d = kd * per_tick / (table::D_DUTY_PER_TICK_PER_S * model.stall_torque);
    [p, d].map(|g| g.round().clamp(0.0, 255.0) as u8)
}

/// The Torque Limit (0.1 %) that caps the output at `torque` N·m (at least 1).
pub fn torque_limit_for(torque: f64, model: &FeetechModel) -> u16 {
    (torque.abs() / model.stall_torque * 1000.0)
        .floor()
        .clamp(1.0, 1000.0) as u16
}

/// What a servo last reported.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeetechFeedback<I> {
    /// Joint angle, rad.
    pub q: f64,
    /// Joint speed, rad/s.
    pub qd: f64,
    /// Joint torque from the reported load, N·m.
    pub tau: f64,
    /// Servo temperature, °C.
    pub temperature: u8,
    /// Supply, V.
    pub voltage: f64,
    /// Error bits in force (status byte).
    pub status: u8,
    /// When the state arrived.
    pub received_at: Option<I>,
    /// Cycles since the last fresh state (`u32::MAX`: never heard).
    pub missed_cycles: u32,
}

impl<I: BusInstant> FeetechFeedback<I> {
    /// True when the last cycle brought no state.
    pub fn is_stale(&self) -> bool {
        self.missed_cycles > 0
    }
}

/// What one read cycle brought.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FeetechReport {
    /// Joints with fresh state.
    pub fresh: usize,
    /// Joints without.
    pub stale: usize,
    /// Status packets dropped (checksum, malformed, another ID in a joint's place).
    pub rejected: usize,
}

/// What went wrong.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FeetechError {
    /// The line failed.
    #[error("Feetech line: {0}")]
    Link(LinkError),
    /// A joint's configuration cannot work.
    #[error("joint {joint}: {reason}")]
    Config {
        /// Joint name.
        joint: String,
        /// Why.
        reason: String,
    },
    /// A servo did not answer.
    #[error("joint {joint}: servo {id} does not answer")]
    NoReply {
        /// Joint name.
        joint: String,
        /// Servo ID.
        id: u8,
    },
    /// A servo answered as another model.
    #[error("joint {joint}: servo {id} is model {found}, robot.toml says {expected} ({number})")]
    WrongModel {
        /// Joint name.
        joint: String,
        /// Servo ID.
        id: u8,
        /// Model name configured.
        expected: String,
        /// Its model number.
        number: u16,
        /// Model number found.
        found: u16,
    },
    /// A goal is NaN or infinite: nothing was sent.
    #[error("joint {joint}: goal {value} is not finite")]
    NotFinite {
        /// Joint name.
        joint: String,
        /// The value.
        value: f64,
    },
    /// Commands for another number of joints.
    #[error("{actual} commands for {expected} joints")]
    CommandCount {
        /// Joints.
        expected: usize,
        /// Commands.
        actual: usize,
    },
    /// Statuses collected before a sync read went out.
    #[error("statuses collected before a sync read was sent")]
    NoRead,
}

/// Counters since start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FeetechStats {
    /// Sync reads.
    pub reads: u64,
    /// Sync writes.
    pub writes: u64,
    /// States missed.
    pub missed: u64,
    /// Statuses dropped.
    pub rejected: u64,
    /// Statuses from a sync read that missed its deadline, come late.
    pub late: u64,
}

/// Options.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeetechDriverOptions {
    /// Margin on top of the wire time of a reply, for the host's scheduler and USB latency.
    pub reply_slack: Duration,
}

impl Default for FeetechDriverOptions {
    fn default() -> Self {
        Self {
            reply_slack: Duration::from_millis(2),
        }
    }
}

/// Bytes of a status packet around its parameters.
const STATUS_OVERHEAD: usize = 6;

/// STS servos on one line.
#[derive(Debug)]
pub struct FeetechBusDriver<T: FeetechTransport> {
    transport: T,
    joints: Vec<FeetechJointConfig>,
    feedback: Vec<FeetechFeedback<T::Instant>>,
    received: Vec<bool>,
    options: FeetechDriverOptions,
    tx: Vec<u8>,
    state_deadline: Option<T::Instant>,
    stats: FeetechStats,
}

impl<T: FeetechTransport> FeetechBusDriver<T> {
    /// A driver for `joints` on `transport`.
    pub fn new(
        transport: T,
        joints: Vec<FeetechJointConfig>,
        options: FeetechDriverOptions,
    ) -> Result<Self, FeetechError> {
        for (i, j) in joints.iter().enumerate() {
            let bad = |reason: String| {
                Err(FeetechError::Config {
                    joint: j.name.clone(),
                    reason,
                })
            };
            if j.id >= BROADCAST_ID {
                return bad(format!("ID {} is not a servo ID (0–253)", j.id));
            }
            if let Some(o) = joints[..i].iter().find(|o| o.id == j.id) {
                return bad(format!("ID {} is also joint {}'s", j.id, o.name));
            }
            if j.direction != 1.0 && j.direction != -1.0 {
                return bad(format!("direction = {}: must be 1 or -1", j.direction));
            }
            if !(j.zero_ticks.is_finite() && (0.0..4096.0).contains(&j.zero_ticks)) {
                return bad(format!("zero at {} ticks: must be within 0–4095", j.zero_ticks));
            }
            if j.homing_offset.abs() > 2047 {
                return bad(format!("homing offset {}: must be within ±2047", j.homing_offset));
            }
        }
        let n = joints.len();
        let blank = FeetechFeedback {
            q: 0.0,
            qd: 0.0,
            tau: 0.0,
            temperature: 0,
            voltage: 0.0,
            status: 0,
            received_at: None,
            missed_cycles: u32::MAX,
        };
        Ok(Self {
            transport,
            joints,
            feedback: vec![blank; n],
            received: vec![false; n],
            options,
            tx: Vec::with_capacity(2 + n * 5),
            state_deadline: None,
            stats: FeetechStats::default(),
        })
    }

    /// The joints, in command order.
    pub fn joints(&self) -> &[FeetechJointConfig] {
        &self.joints
    }

    /// The latest state per joint.
    pub fn feedback(&self) -> &[FeetechFeedback<T::Instant>] {
        &self.feedback
    }

    /// Counters.
    pub fn stats(&self) -> FeetechStats {
        self.stats
    }

    /// The transport.
    pub fn transport_mut(&mut self) -> &mut T {
        &mut self.transport
    }

    fn deadline(&self, request: usize, reply: usize) -> T::Instant {
        let budget = crate::half_duplex::reply_budget(
            self.transport.baud(),
            request + reply,
            self.joints.len(),
            Duration::ZERO,
            self.options.reply_slack,
        );
        self.transport.now() + budget
    }

    /// Sends an instruction to one servo and returns its status's parameters into `out`.
    fn exchange(&mut self, id: u8, instruction: u8, params: &[u8], out: &mut [u8]) -> Result<u8, LinkError> {
        self.transport.send(id, instruction, params)?;
        let deadline = self.deadline(params.len() + 6, out.len() + STATUS_OVERHEAD);
        loop {
            let s = self.transport.recv_status(deadline)?;
            if s.id != id {
                continue;
            }
            if s.params.len() != out.len() {
                return Err(LinkError::Malformed);
            }
            out.copy_from_slice(s.params);
            return Ok(s.error);
        }
    }

    /// Pings servo `id`: its model number and firmware version, or `None` when it is silent.
    pub fn ping(&mut self, id: u8) -> Result<Option<(u16, [u8; 2])>, FeetechError> {
        for _ in 0..3 {
            match self.exchange(id, inst::PING, &[], &mut []) {
                Ok(_) => {
                    let mut b = [0u8; 5];
                    match self.read(id, addr::FIRMWARE_MAJOR, &mut b) {
                        Ok(()) => return Ok(Some((u16::from_le_bytes([b[3], b[4]]), [b[0], b[1]]))),
                        Err(FeetechError::Link(LinkError::Io(e))) => {
                            return Err(FeetechError::Link(LinkError::Io(e)));
                        }
                        // A late or garbled answer to the model read: ask again.
                        Err(_) => {}
                    }
                }
                Err(LinkError::Io(e)) => return Err(FeetechError::Link(LinkError::Io(e))),
                Err(_) => {}
            }
        }
        Ok(None)
    }

    /// Reads `out.len()` bytes from `address` of servo `id`.
    pub fn read(&mut self, id: u8, address: u8, out: &mut [u8]) -> Result<(), FeetechError> {
        let len = out.len() as u8;
        self.exchange(id, inst::READ, &[address, len], out)
            .map(|_| ())
            .map_err(FeetechError::Link)
    }

    /// Writes `data` at `address` of servo `id` and waits for its status.
    pub fn write(&mut self, id: u8, address: u8, data: &[u8]) -> Result<(), FeetechError> {
        let mut params = [0u8; 64];
        params[0] = address;
        params[1..=data.len()].copy_from_slice(data);
        self.exchange(id, inst::WRITE, &params[..=data.len()], &mut [])
            .map(|_| ())
            .map_err(FeetechError::Link)
    }

    /// Checks every servo answers as its model, then, output off and EPROM unlocked, programs
    /// position mode, homing offset and gains, locks the EPROM, sets the torque limits, and reads
    /// the state once.
    pub fn configure(&mut self) -> Result<(), FeetechError> {
        for k in 0..self.joints.len() {
            let j = self.joints[k].clone();
            match self.ping(j.id)? {
                None => {
                    return Err(FeetechError::NoReply {
                        joint: j.name,
                        id: j.id,
                    });
                }
                Some((number, _)) if number != j.model.model_number => {
                    return Err(FeetechError::WrongModel {
                        joint: j.name,
                        id: j.id,
                        expected: j.model.name.clone(),
                        number: j.model.model_number,
                        found: number,
                    });
                }
                Some(_) => {}
            }
            self.write(j.id, addr::TORQUE_ENABLE, &[0])?;
            self.write(j.id, addr::LOCK, &[0])?;
            self.write(j.id, addr::MODE, &[0])?;
            self.write(
                j.id,
                addr::HOMING_OFFSET,
                &to_sign_magnitude(-j.homing_offset, 11).to_le_bytes(),
            )?;
            self.write(j.id, addr::P_GAIN, &j.gains.unwrap_or([32, 32]))?;
            self.write(j.id, addr::LOCK, &[1])?;
            if let Some(limit) = j.torque_limit {
                self.write(j.id, addr::TORQUE_LIMIT, &limit.min(1000).to_le_bytes())?;
            }
        }
        self.read_state()?;
        Ok(())
    }

    /// One sync write of `width` bytes from `address`: `fill(joint, bytes)` gives each joint's.
    fn sync_write(
        &mut self,
        address: u8,
        width: usize,
        mut fill: impl FnMut(usize, &FeetechJointConfig, &mut [u8]),
    ) -> Result<(), FeetechError> {
        self.tx.clear();
        self.tx.extend_from_slice(&[address, width as u8]);
        for (k, j) in self.joints.iter().enumerate() {
            self.tx.push(j.id);
            let at = self.tx.len();
            self.tx.resize(at + width, 0);
            fill(k, j, &mut self.tx[at..]);
        }
        self.transport
            .send(BROADCAST_ID, inst::SYNC_WRITE, &self.tx)
            .map_err(FeetechError::Link)?;
        self.stats.writes += 1;
        Ok(())
    }

    /// Goal positions (joint angles, rad), one sync write. Refuses non-finite goals, sending
    /// nothing.
    pub fn write_goals(&mut self, q: &[f64]) -> Result<(), FeetechError> {
        if q.len() != self.joints.len() {
            return Err(FeetechError::CommandCount {
                expected: self.joints.len(),
                actual: q.len(),
            });
        }
        if let Some((j, &value)) = self.joints.iter().zip(q).find(|(_, v)| !v.is_finite()) {
            return Err(FeetechError::NotFinite {
                joint: j.name.clone(),
                value,
            });
        }
        self.sync_write(addr::GOAL_POSITION, 2, |k, j, b| {
            b.copy_from_slice(&to_sign_magnitude(j.ticks_of(q[k]), 15).to_le_bytes());
        })
    }

    /// Position P and D coefficients per joint, one sync write.
    pub fn write_gains(&mut self, gains: &[[u8; 2]]) -> Result<(), FeetechError> {
        self.sync_write(addr::P_GAIN, 2, |k, _, b| b.copy_from_slice(&gains[k]))
    }

    /// Output on for every servo.
    pub fn enable(&mut self) -> Result<(), FeetechError> {
        self.sync_write(addr::TORQUE_ENABLE, 1, |_, _, b| b[0] = 1)
    }

    /// Output off for every servo.
    pub fn disable(&mut self) -> Result<(), FeetechError> {
        self.sync_write(addr::TORQUE_ENABLE, 1, |_, _, b| b[0] = 0)
    }

    /// Sends the sync read of the state block; [`Self::collect_state`] takes the answers.
    pub fn request_state(&mut self) -> Result<(), FeetechError> {
        self.tx.clear();
        self.tx.extend_from_slice(&[table::STATE_START, table::STATE_LEN]);
        self.tx.extend(self.joints.iter().map(|j| j.id));
        self.transport
            .send(BROADCAST_ID, inst::SYNC_READ, &self.tx)
            .map_err(FeetechError::Link)?;
        self.stats.reads += 1;
        let reply = self.joints.len() * (STATUS_OVERHEAD + usize::from(table::STATE_LEN));
        self.state_deadline = Some(self.deadline(self.tx.len() + 6, reply));
        Ok(())
    }

    /// Takes the servos' answers to the last sync read, in list order, until all are in or the
    /// deadline passes.
    pub fn collect_state(&mut self) -> Result<FeetechReport, FeetechError> {
        let deadline = self.state_deadline.take().ok_or(FeetechError::NoRead)?;
        self.received.fill(false);
        let mut report = FeetechReport::default();
        let mut outstanding = self.joints.len();
        while outstanding > 0 {
            match self.transport.recv_status(deadline) {
                Ok(s) => {
                    let Some(i) = self.joints.iter().position(|j| j.id == s.id) else {
                        report.rejected += 1;
                        continue;
                    };
                    if self.received[i] {
                        self.stats.late += 1;
                        continue;
                    }
                    if s.params.len() != usize::from(table::STATE_LEN) {
                        report.rejected += 1;
                        continue;
                    }
                    decode_state(&self.joints[i], s.params, s.error, &mut self.feedback[i]);
                    let now = self.transport.now();
                    let fb = &mut self.feedback[i];
                    fb.received_at = Some(now);
                    fb.missed_cycles = 0;
                    self.received[i] = true;
                    outstanding -= 1;
                }
                Err(LinkError::Timeout) => break,
                Err(e @ LinkError::Io(_)) => return Err(FeetechError::Link(e)),
                Err(_) => report.rejected += 1,
            }
        }
        for (fb, &heard) in self.feedback.iter_mut().zip(&self.received) {
            if heard {
                report.fresh += 1;
            } else {
                fb.missed_cycles = if fb.received_at.is_none() {
                    u32::MAX
                } else {
                    fb.missed_cycles.saturating_add(1)
                };
                report.stale += 1;
            }
        }
        self.stats.missed += report.stale as u64;
        self.stats.rejected += report.rejected as u64;
        Ok(report)
    }

    /// A whole read: sync read and its answers.
    pub fn read_state(&mut self) -> Result<FeetechReport, FeetechError> {
        self.request_state()?;
        self.collect_state()
    }

    /// One tick's traffic: goals, then state.
    pub fn cycle(&mut self, q: &[f64]) -> Result<FeetechReport, FeetechError> {
        self.write_goals(q)?;
        self.read_state()
    }
}

/// What one ID answered during a [`scan`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScanHit {
    /// Servo ID.
    pub id: u8,
    /// Model number (address 3).
    pub model_number: u16,
    /// Firmware major and minor version.
    pub firmware: [u8; 2],
    /// Present position, ticks (`None`: the state read came back late or garbled).
    pub position: Option<u16>,
    /// Present temperature, °C (`None`: not read).
    pub temperature: Option<u8>,
    /// Error bits in force (Status, 65; `None`: not read).
    pub status: Option<u8>,
}

/// Pings each ID in `ids` (three tries each, `timeout` per answer) and reads what answered:
/// identity, position, temperature, status. Only reads; nothing is written.
pub fn scan<T: FeetechTransport>(
    port: T,
    ids: impl IntoIterator<Item = u8>,
    timeout: Duration,
) -> Result<Vec<ScanHit>, FeetechError> {
    let options = FeetechDriverOptions { reply_slack: timeout };
    let mut d = FeetechBusDriver::new(port, Vec::new(), options)?;
    let mut hits = Vec::new();
    for id in ids {
        let Some((model_number, firmware)) = d.ping(id)? else {
            continue;
        };
        // A servo whose state read comes back late or garbled is still listed, its readings
        // unknown (not zero: a servo at 0 rad and 0 °C would be a reading); one bad reply never
        // ends the scan of the others.
        let mut state = [0u8; 10];
        let read = match d.read(id, addr::PRESENT_POSITION, &mut state) {
            Err(FeetechError::Link(LinkError::Io(e))) => return Err(FeetechError::Link(LinkError::Io(e))),
            Err(_) => None,
            Ok(_) => Some(state),
        };
        hits.push(ScanHit {
            id,
            model_number,
            firmware,
            position: read.map(|s| u16::from_le_bytes([s[0], s[1]])),
            temperature: read.map(|s| s[usize::from(addr::PRESENT_TEMPERATURE - addr::PRESENT_POSITION)]),
            status: read.map(|s| s[usize::from(addr::STATUS - addr::PRESENT_POSITION)]),
        });
    }
    Ok(hits)
}

/// The names of error bits, for people.
pub fn error_names(bits: u8) -> String {
    use super::packet::error;
    let names: Vec<&str> = [
        (error::VOLTAGE, "voltage"),
        (error::ANGLE_SENSOR, "angle sensor"),
        (error::OVERHEAT, "overheat"),
        (error::OVERCURRENT, "overcurrent"),
        (error::OVERLOAD, "overload"),
    ]
    .into_iter()
    .filter(|(b, _)| bits & b != 0)
    .map(|(_, n)| n)
    .collect();
    names.join(", ")
}

/// The state block (56…70) into a joint's feedback.
fn decode_state<I>(j: &FeetechJointConfig, b: &[u8], status: u8, fb: &mut FeetechFeedback<I>) {
    let word = |at: u8| {
        u16::from_le_bytes([
            b[usize::from(at - table::STATE_START)],
            b[usize::from(at - table::STATE_START) + 1],
        ])
    };
    let byte = |at: u8| b[usize::from(at - table::STATE_START)];
    let ticks = i32::from(word(addr::PRESENT_POSITION));
    fb.q = j.rad_of(ticks);
    fb.qd =
        j.direction * f64::from(from_sign_magnitude(word(addr::PRESENT_SPEED), 15)) * table::rad_per_tick();
    // Load is the duty in 0.1 %: at stall, torque follows it.
    fb.tau = j.direction * f64::from(from_sign_magnitude(word(addr::PRESENT_LOAD), 10)) / 1000.0
        * j.model.stall_torque;
    fb.voltage = f64::from(byte(addr::PRESENT_VOLTAGE)) / 10.0;
    fb.temperature = byte(addr::PRESENT_TEMPERATURE);
    fb.status = status | byte(addr::STATUS);
}
