//! Host driver for MIT-mode motors on one CAN bus.
//!
//! Per control tick, [`MitBusDriver::cycle`] sends one command per motor back to back and collects
//! one reply per motor until all are in or the deadline passes; it never waits past the deadline.
//! A motor whose reply is missing keeps its last feedback, marked stale with its age. Joint-side
//! units (what the policy sees) are converted to motor-side units with a per-joint direction, zero
//! offset and external gear ratio. Buffers are sized at construction: a cycle does not allocate.

use std::time::Duration;

use super::codec::{
    CodecError, MitCommand, MotorFault, SpecialFrame, command_frame, decode_reply_frame, reply_names,
    special_frame,
};
use super::models::MotorModel;
use crate::can::{CanBus, CanError, CanFrame, CanId};
use crate::time::BusInstant;

/// Wire time of one cycle at `bitrate` of `mit` MIT-mode motors (11-bit IDs) and `robstride`
/// Robstride motors (29-bit IDs): a command and a reply each, every frame at its worst-case length
/// (8 data bytes, every stuff bit).
pub fn cycle_wire_time(mit: usize, robstride: usize, bitrate: u32) -> Duration {
    let frame = |extended| u64::from(crate::can::wire_time::worst_case_bits(8, extended));
    let bits = 2 * (mit as u64 * frame(false) + robstride as u64 * frame(true));
    Duration::from_nanos((bits * 1_000_000_000).div_ceil(u64::from(bitrate.max(1))))
}

/// Times an enable or disable is sent before a silent motor counts as missing.
pub const SPECIAL_TRIES: usize = 3;

/// Most motors one driver (one bus) handles.
pub const MAX_MOTORS_PER_BUS: usize = 32;

/// One joint driven by an MIT motor.
#[derive(Debug, Clone, PartialEq)]
pub struct MitJointConfig {
    /// Joint name, for errors and logs.
    pub name: String,
    /// The motor's CAN ID (1–127 typical).
    pub motor_id: u8,
    /// The CAN ID the motor replies on.
    pub reply_id: u16,
    /// Ranges and reply format.
    pub model: MotorModel,
    /// +1 or −1: sign between joint angle and motor angle.
    pub direction: f64,
    /// Motor angle at joint zero, rad.
    pub offset: f64,
    /// Motor turns per joint turn (external reduction after the motor's output), ≥ 1 typically.
    pub gear_ratio: f64,
    /// The most torque the motor may give, N·m at the motor, for motors whose protocol carries a
    /// limit (Robstride's `limit_torque`): written when the bus is identified, so the motor's own
    /// loop holds it between commands. `None`: the motor's full range.
    pub torque_limit: Option<f64>,
}

impl MitJointConfig {
    /// A joint on motor `motor_id` with the family's default reply ID, positive direction, no
    /// offset and no external gearing; adjust the fields that differ.
    pub fn new(name: &str, motor_id: u8, model: &MotorModel) -> Self {
        Self {
            name: name.to_owned(),
            motor_id,
            reply_id: model.family.default_reply_id(motor_id),
            model: model.clone(),
            direction: 1.0,
            offset: 0.0,
            gear_ratio: 1.0,
            torque_limit: None,
        }
    }

    /// A joint-side command in the motor's units: through the direction, zero offset and gear.
    pub fn to_motor(&self, c: &JointCommand) -> MitCommand {
        let (s, g) = (self.direction, self.gear_ratio);
        MitCommand {
            p: s * g * c.q + self.offset,
            v: s * g * c.qd,
            kp: c.kp / (g * g),
            kd: c.kd / (g * g),
            t: s * c.tau / g,
        }
    }

    /// The motor's position, velocity and torque as the joint's: `(q, qd, tau)`.
    pub fn to_joint(&self, p: f64, v: f64, t: f64) -> (f64, f64, f64) {
        let (s, g) = (self.direction, self.gear_ratio);
        (s * (p - self.offset) / g, s * v / g, s * t * g)
    }
}

/// A command in joint units.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JointCommand {
    /// Position setpoint, rad.
    pub q: f64,
    /// Velocity setpoint, rad/s.
    pub qd: f64,
    /// Stiffness, N·m/rad.
    pub kp: f64,
    /// Damping, N·m·s/rad.
    pub kd: f64,
    /// Feed-forward torque, N·m.
    pub tau: f64,
}

/// The latest feedback of one joint, in joint units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointFeedback<I> {
    /// Angle, rad.
    pub q: f64,
    /// Velocity, rad/s.
    pub qd: f64,
    /// Torque, N·m.
    pub tau: f64,
    /// Winding temperature, °C, where reported.
    pub temperature: Option<f64>,
    /// Reported fault.
    pub fault: MotorFault,
    /// Torque on/off, where reported.
    pub enabled: Option<bool>,
    /// When the last reply arrived (`None`: never).
    pub received_at: Option<I>,
    /// Consecutive cycles without a reply (0: fresh this cycle).
    pub missed_cycles: u32,
}

impl<I: BusInstant> JointFeedback<I> {
    /// True when the last cycle brought no reply.
    pub fn is_stale(&self) -> bool {
        self.missed_cycles > 0
    }

    /// Time since the last reply, at `now` (`None`: never received).
    pub fn age(&self, now: I) -> Option<Duration> {
        self.received_at.map(|t| now - t)
    }
}

/// Errors of the MIT driver, each naming the joint and motor.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MitError {
    /// The transport failed.
    #[error(transparent)]
    Bus(#[from] CanError),
    /// The configuration is inconsistent.
    #[error("joint {joint}: {reason}")]
    Config {
        /// The joint.
        joint: String,
        /// What is wrong.
        reason: String,
    },
    /// A motor did not answer in time.
    #[error("joint {joint} (motor ID {motor_id}) did not answer within {timeout:?}")]
    NoReply {
        /// The joint.
        joint: String,
        /// The motor's CAN ID.
        motor_id: u8,
        /// How long the driver waited.
        timeout: Duration,
    },
    /// A command could not be packed (NaN or infinite field).
    #[error("joint {joint}: {source}")]
    Command {
        /// The joint.
        joint: String,
        /// The codec's refusal.
        source: CodecError,
    },
    /// The number of commands does not match the number of joints.
    #[error("{actual} commands for {expected} joints")]
    CommandCount {
        /// Joints on the bus.
        expected: usize,
        /// Commands given.
        actual: usize,
    },
}

/// Frames that arrived but were not usable replies, by kind.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RxRejects {
    /// Frames on an ID no motor replies on.
    pub unknown_id: u64,
    /// Frames whose payload names a motor not on this bus.
    pub unknown_motor: u64,
    /// Frames of the wrong length for the motor's format.
    pub wrong_length: u64,
    /// Extra replies from a motor already heard this cycle (late replies of an earlier cycle).
    pub duplicate: u64,
}

/// What one cycle did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CycleReport {
    /// Replies received.
    pub replies: usize,
    /// Motors that did not answer before the deadline.
    pub missing: usize,
    /// Commands that had to be clamped to their motor's range.
    pub clamped: usize,
    /// Frames rejected this cycle.
    pub rejected: usize,
}

/// Counters since start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DriverStats {
    /// Cycles run.
    pub cycles: u64,
    /// Replies missed, summed over motors.
    pub missed_replies: u64,
    /// Replies that arrived after their cycle's deadline, dropped before the next commands.
    pub late_replies: u64,
    /// Commands clamped.
    pub clamped: u64,
    /// Rejected frames by kind.
    pub rejects: RxRejects,
}

/// MIT motors on one bus.
#[derive(Debug)]
pub struct MitBusDriver<B: CanBus> {
    bus: B,
    joints: Vec<MitJointConfig>,
    feedback: Vec<JointFeedback<B::Instant>>,
    answered: Vec<bool>,
    reply_timeout: Duration,
    /// When the replies to the commands last sent are due.
    reply_deadline: Option<B::Instant>,
    /// What the commands last sent did, until their replies are collected.
    pending: CycleReport,
    stats: DriverStats,
}

impl<B: CanBus> MitBusDriver<B> {
    /// A driver for `joints` on `bus`; `reply_timeout` bounds every wait for replies.
    pub fn new(bus: B, joints: Vec<MitJointConfig>, reply_timeout: Duration) -> Result<Self, MitError> {
        if joints.len() > MAX_MOTORS_PER_BUS {
            return Err(MitError::Config {
                joint: joints[MAX_MOTORS_PER_BUS].name.clone(),
                reason: format!("more than {MAX_MOTORS_PER_BUS} motors on one bus"),
            });
        }
        for (i, j) in joints.iter().enumerate() {
            let bad = |reason: String| {
                Err(MitError::Config {
                    joint: j.name.clone(),
                    reason,
                })
            };
            if j.direction != 1.0 && j.direction != -1.0 {
                return bad(format!("direction = {}: must be 1 or -1", j.direction));
            }
            if !(j.gear_ratio.is_finite() && j.gear_ratio > 0.0) {
                return bad(format!("gear_ratio = {}: must be positive", j.gear_ratio));
            }
            if !j.offset.is_finite() {
                return bad(format!("offset = {}: must be finite", j.offset));
            }
            if j.motor_id > 0x7F || j.reply_id > 0x7FF {
                return bad(format!(
                    "motor ID {} / reply ID {:#x} out of range",
                    j.motor_id, j.reply_id
                ));
            }
            if let Some(other) = joints[..i].iter().find(|o| o.motor_id == j.motor_id) {
                return bad(format!(
                    "motor ID {} is also used by joint {}",
                    j.motor_id, other.name
                ));
            }
        }
        let n = joints.len();
        let blank = JointFeedback {
            q: 0.0,
            qd: 0.0,
            tau: 0.0,
            temperature: None,
            fault: MotorFault::None,
            enabled: None,
            received_at: None,
            missed_cycles: 0,
        };
        Ok(Self {
            bus,
            joints,
            feedback: vec![blank; n],
            answered: vec![false; n],
            reply_timeout,
            reply_deadline: None,
            pending: CycleReport::default(),
            stats: DriverStats::default(),
        })
    }

    /// The joints, in command order.
    pub fn joints(&self) -> &[MitJointConfig] {
        &self.joints
    }

    /// Latest feedback per joint.
    pub fn feedback(&self) -> &[JointFeedback<B::Instant>] {
        &self.feedback
    }

    /// Counters since start.
    pub fn stats(&self) -> DriverStats {
        self.stats
    }

    /// The transport's clock.
    pub fn now(&self) -> B::Instant {
        self.bus.now()
    }

    /// The transport.
    pub fn bus_mut(&mut self) -> &mut B {
        &mut self.bus
    }

    /// Sends one command per joint and collects replies until all are in or `reply_timeout` passes.
    pub fn cycle(&mut self, commands: &[JointCommand]) -> Result<CycleReport, MitError> {
        self.send_commands(commands)?;
        self.collect_replies()
    }

    /// The first half of a cycle: sends one command per joint back to back. Their replies are due
    /// within `reply_timeout`; [`Self::collect_replies`] takes them. Between the two, other buses
    /// can be served (a scheduler running several buses in one thread).
    pub fn send_commands(&mut self, commands: &[JointCommand]) -> Result<(), MitError> {
        if commands.len() != self.joints.len() {
            return Err(MitError::CommandCount {
                expected: self.joints.len(),
                actual: commands.len(),
            });
        }
        let mut report = CycleReport::default();
        // Pack everything before sending anything: a bad command must not leave half a bus commanded.
        let mut frames = [CanFrame::new8(CanId::Standard(0), [0; 8]); MAX_MOTORS_PER_BUS];
        for (i, (j, c)) in self.joints.iter().zip(commands).enumerate() {
            let cmd = j.to_motor(c);
            if super::codec::needs_clamp(&j.model, &cmd) {
                report.clamped += 1;
            }
            frames[i] = command_frame(&j.model, j.motor_id, &cmd).map_err(|source| MitError::Command {
                joint: j.name.clone(),
                source,
            })?;
        }
        // Replies that came after their cycle's deadline would pass for this cycle's (MIT replies
        // carry no sequence number): drop what has arrived before the commands go out.
        let now = self.bus.now();
        while self.bus.recv_until(now)?.is_some() {
            self.stats.late_replies += 1;
        }
        self.reply_deadline = Some(now + self.reply_timeout);
        for f in &frames[..self.joints.len()] {
            self.bus.send(f)?;
        }
        self.pending = report;
        Ok(())
    }

    /// The second half of a cycle: collects one reply per motor until all are in or the deadline
    /// set when the commands went out passes (at once, if it has passed: only what has arrived).
    pub fn collect_replies(&mut self) -> Result<CycleReport, MitError> {
        let mut report = std::mem::take(&mut self.pending);
        self.collect(&mut report)?;
        self.stats.cycles += 1;
        self.stats.clamped += report.clamped as u64;
        Ok(report)
    }

    fn collect(&mut self, report: &mut CycleReport) -> Result<(), MitError> {
        self.answered.fill(false);
        let deadline = self
            .reply_deadline
            .take()
            .unwrap_or_else(|| self.bus.now() + self.reply_timeout);
        let mut outstanding = self.joints.len();
        while outstanding > 0 {
            let Some(frame) = self.bus.recv_until(deadline)? else {
                break;
            };
            match self.accept(&frame) {
                Ok(()) => {
                    outstanding -= 1;
                    report.replies += 1;
                }
                Err(()) => report.rejected += 1,
            }
        }
        for (fb, answered) in self.feedback.iter_mut().zip(&self.answered) {
            if !answered {
                fb.missed_cycles = fb.missed_cycles.saturating_add(1);
                report.missing += 1;
            }
        }
        self.stats.missed_replies += report.missing as u64;
        Ok(())
    }

    /// Decodes one received frame into its joint's feedback, or counts why it was rejected.
    fn accept(&mut self, frame: &CanFrame) -> Result<(), ()> {
        // CubeMars replies share one ID: the payload's first byte names the motor. DaMiao puts its
        // state in that byte's high nibble; its low nibble and the reply ID name the motor.
        // Robstride names motor and host in the 29-bit ID.
        let mut known_id = false;
        let mut decoded = None;
        let mut short = false;
        for (i, j) in self.joints.iter().enumerate() {
            let addressed = match j.model.family {
                super::models::MotorFamily::Robstride => super::robstride::split_id(frame.id())
                    .is_some_and(|(_, _, host)| u16::from(host) == j.reply_id),
                _ => frame.id() == CanId::Standard(j.reply_id),
            };
            if !addressed {
                continue;
            }
            let Some((_, r)) = decode_reply_frame(&j.model, frame) else {
                // On a reply ID, only the length fails to decode (or, for Robstride, another type).
                short |= frame.data().len() != super::codec::reply_len(j.model.family);
                continue;
            };
            known_id = true;
            if reply_names(&j.model, &r, j.motor_id) {
                decoded = Some((i, r));
                break;
            }
        }
        let Some((i, r)) = decoded else {
            if known_id {
                self.stats.rejects.unknown_motor += 1;
            } else if short {
                self.stats.rejects.wrong_length += 1;
            } else {
                self.stats.rejects.unknown_id += 1;
            }
            return Err(());
        };
        let j = &self.joints[i];
        if self.answered[i] {
            self.stats.rejects.duplicate += 1;
            return Err(());
        }
        let fb = &mut self.feedback[i];
        (fb.q, fb.qd, fb.tau) = j.to_joint(r.p, r.v, r.t);
        fb.temperature = r.temperature;
        fb.fault = r.fault;
        fb.enabled = r.enabled;
        fb.received_at = Some(self.bus.now());
        fb.missed_cycles = 0;
        self.answered[i] = true;
        Ok(())
    }

    /// Sends `which` to every motor and waits for every reply, asking again (up to
    /// [`SPECIAL_TRIES`] times) while one is missing: a late reply on a busy host is not a
    /// missing motor, and these frames may be repeated.
    fn special_all(&mut self, which: SpecialFrame) -> Result<(), MitError> {
        for _ in 0..SPECIAL_TRIES {
            for j in &self.joints {
                self.bus
                    .send(&special_frame(&j.model, j.motor_id, j.reply_id, which))?;
            }
            self.reply_deadline = None;
            let mut report = CycleReport::default();
            self.collect(&mut report)?;
            if self.answered.iter().all(|&a| a) {
                return Ok(());
            }
        }
        let i = self.answered.iter().position(|a| !a).unwrap_or(0);
        Err(MitError::NoReply {
            joint: self.joints[i].name.clone(),
            motor_id: self.joints[i].motor_id,
            timeout: self.reply_timeout,
        })
    }

    /// Turns every motor's torque on; fails naming the first motor that did not answer.
    /// Robstride motors are first put in run mode 0 (operation control: the impedance law the
    /// commands drive), which they take only while stopped; a motor left in position or velocity
    /// mode by another tool would otherwise ignore every command.
    pub fn enable_all(&mut self) -> Result<(), MitError> {
        use super::robstride::{self, comm, param};
        for i in 0..self.joints.len() {
            let j = &self.joints[i];
            if j.model.family != super::models::MotorFamily::Robstride {
                continue;
            }
            let (motor, host) = (j.motor_id, j.reply_id as u8);
            let frame = robstride::write_param(motor, host, param::RUN_MODE, [0; 4]);
            if self
                .ask(&frame, |kind, data2| {
                    kind == comm::FEEDBACK && data2 as u8 == motor
                })?
                .is_none()
            {
                return Err(MitError::NoReply {
                    joint: self.joints[i].name.clone(),
                    motor_id: motor,
                    timeout: self.reply_timeout,
                });
            }
        }
        self.special_all(SpecialFrame::Enable)
    }

    /// Turns every motor's torque off; fails naming the first motor that did not answer.
    pub fn disable_all(&mut self) -> Result<(), MitError> {
        self.special_all(SpecialFrame::Disable)
    }

    /// Takes every motor's current position as its zero (motors must be disabled).
    pub fn set_zero_all(&mut self) -> Result<(), MitError> {
        self.special_all(SpecialFrame::SetZero)
    }
}

/// Who a Robstride motor says it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobstrideIdentity {
    /// The MCU's 64-bit unique ID (get-ID answer).
    pub uid: u64,
    /// The torque limit in its parameter table (`limit_torque`), N·m.
    pub torque_limit: f64,
}

impl<B: CanBus> MitBusDriver<B> {
    /// Asks joint `joint`'s Robstride motor its unique ID and torque limit (each asked up to
    /// [`SPECIAL_TRIES`] times); `None` for a joint on another protocol or a motor that does not
    /// answer. Not for use inside a cycle: it reads the bus until its answers come.
    pub fn robstride_identity(&mut self, joint: usize) -> Result<Option<RobstrideIdentity>, MitError> {
        use super::robstride::{self, comm, param};
        let Some(j) = self.joints.get(joint) else {
            return Ok(None);
        };
        if j.model.family != super::models::MotorFamily::Robstride {
            return Ok(None);
        }
        let (motor, host) = (j.motor_id, j.reply_id as u8);
        let get_id = CanFrame::new8(robstride::frame_id(comm::GET_ID, u16::from(host), motor), [0; 8]);
        let Some(id) = self.ask(&get_id, |kind, data2| {
            kind == comm::GET_ID && data2 as u8 == motor
        })?
        else {
            return Ok(None);
        };
        let read = robstride::read_param(motor, host, param::LIMIT_TORQUE);
        let answer = self.ask(&read, |kind, data2| {
            kind == comm::READ_PARAM && data2 == u16::from(motor)
        })?;
        let Some((param::LIMIT_TORQUE, value)) = answer.and_then(|f| robstride::param_of(f.data())) else {
            return Ok(None);
        };
        let mut uid = [0u8; 8];
        uid[..id.data().len()].copy_from_slice(id.data());
        Ok(Some(RobstrideIdentity {
            uid: u64::from_le_bytes(uid),
            torque_limit: f64::from(f32::from_le_bytes(value)),
        }))
    }

    /// Writes each Robstride motor's `limit_torque` from its joint's [`MitJointConfig::torque_limit`]
    /// and reads it back; fails naming the joint whose motor did not take it. Motors of other
    /// families, and joints without a limit, are left alone. Not for use inside a cycle.
    pub fn write_torque_limits(&mut self) -> Result<(), MitError> {
        use super::robstride::{self, comm, param};
        for k in 0..self.joints.len() {
            let j = &self.joints[k];
            let Some(limit) = j.torque_limit else { continue };
            if j.model.family != super::models::MotorFamily::Robstride {
                continue;
            }
            let (motor, host, name) = (j.motor_id, j.reply_id as u8, j.name.clone());
            let value = (limit as f32).to_le_bytes();
            self.bus
                .send(&robstride::write_param(motor, host, param::LIMIT_TORQUE, value))?;
            let read = robstride::read_param(motor, host, param::LIMIT_TORQUE);
            let answer = self.ask(&read, |kind, data2| {
                kind == comm::READ_PARAM && data2 == u16::from(motor)
            })?;
            match answer.and_then(|f| robstride::param_of(f.data())) {
                Some((param::LIMIT_TORQUE, v)) if v == value => {}
                got => {
                    return Err(MitError::Config {
                        joint: name,
                        reason: format!(
                            "motor {motor} did not take limit_torque = {limit} N·m (read back {:?})",
                            got.map(|(_, v)| f32::from_le_bytes(v))
                        ),
                    });
                }
            }
        }
        Ok(())
    }

    /// Sends `request` and returns the first extended frame whose type and `data2` `wanted`
    /// accepts, within the reply timeout, asking up to [`SPECIAL_TRIES`] times.
    fn ask(
        &mut self,
        request: &CanFrame,
        wanted: impl Fn(u8, u16) -> bool,
    ) -> Result<Option<CanFrame>, MitError> {
        for _ in 0..SPECIAL_TRIES {
            self.bus.send(request)?;
            let deadline = self.bus.now() + self.reply_timeout;
            while let Some(frame) = self.bus.recv_until(deadline)? {
                if super::robstride::split_id(frame.id()).is_some_and(|(kind, data2, _)| wanted(kind, data2))
                {
                    return Ok(Some(frame));
                }
            }
        }
        Ok(None)
    }
}

/// What one ID answered during a [`scan`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanHit {
    /// The motor ID asked.
    pub motor_id: u8,
    /// The CAN ID the reply came on.
    pub reply_id: u16,
    /// The decoded reply.
    pub reply: super::codec::MitReply,
}

/// Disable frames per ID before a scan calls it missing.
pub const SCAN_TRIES: usize = 3;

fn ask_once<B: CanBus>(
    bus: &mut B,
    model: &MotorModel,
    id: u8,
    timeout: Duration,
) -> Result<Option<ScanHit>, CanError> {
    let host = model.family.default_reply_id(id);
    bus.send(&special_frame(model, id, host, SpecialFrame::Disable))?;
    let deadline = bus.now() + timeout;
    while let Some(frame) = bus.recv_until(deadline)? {
        let Some((reply_id, reply)) = decode_reply_frame(model, &frame) else {
            continue;
        };
        if reply_names(model, &reply, id) {
            return Ok(Some(ScanHit {
                motor_id: id,
                reply_id,
                reply,
            }));
        }
    }
    Ok(None)
}

/// Asks each ID in `ids` for its state with a *disable* frame (torque off: safe on a robot that
/// is not running) and returns the motors that answered (each ID asked up to [`SCAN_TRIES`] times) within `timeout`, decoded as `model`.
pub fn scan<B: CanBus>(
    bus: &mut B,
    model: &MotorModel,
    ids: impl IntoIterator<Item = u8>,
    timeout: Duration,
) -> Result<Vec<ScanHit>, CanError> {
    let mut hits = Vec::new();
    for id in ids {
        // A silent ID is asked again before it counts as missing: one lost or late reply is not
        // an absent motor.
        for _ in 0..SCAN_TRIES {
            if let Some(hit) = ask_once(bus, model, id, timeout)? {
                hits.push(hit);
                break;
            }
        }
    }
    Ok(hits)
}
