//! The emulated board of a Unitree robot: what the robot's own computer does between its motors and
//! the user's DDS link. It publishes `LowState` (IMU, every motor's state, CRC) at its rate, takes a
//! `LowCmd` only when its CRC is right, and runs each motor's impedance law at the motor's rate
//! with the motor's torque limit, temperature and error bits (Unitree's motor status bits). Its
//! faults: the state going silent, its CRC corrupted, a motor dropping out.
//!
//! The board is transport-free: [`UnitreeBoard::receive`] takes a command's CDR,
//! [`UnitreeBoard::publish`] seals a state at each period; [`UnitreeBoard::state_cdr`] encodes it when read.
//! The mirror calls both on simulated time; DDS (wall clock) or a lockstep port carries the bytes.

use std::time::Duration;

use crate::mit::codec::{MitCommand, MotorFault};
use crate::mit::firmware::{InjectedFaults, MitFirmwareConfig, MitMotorFirmware};
use crate::time::SimInstant;

use super::hg::{ImuState, LowCmd, LowState, MotorCmd, Sealed as _};

/// Unitree's motor status bits (`MotorState_::motorstate`), as the G1's documentation lists them.
pub mod motor_bits {
    /// Over-current.
    pub const OVERCURRENT: u32 = 0x1;
    /// Transient under-voltage.
    pub const UNDERVOLTAGE: u32 = 0x8;
    /// MOS over-temperature.
    pub const MOS_OVERHEAT: u32 = 0x20;
    /// Winding over-temperature.
    pub const WINDING_OVERHEAT: u32 = 0x200;
    /// Output encoder error.
    pub const ENCODER: u32 = 0x1000;
    /// The motor judged the computer's commands timed out.
    pub const COMMAND_TIMEOUT: u32 = 0x4000_0000;
    /// The motor's connection timed out (it stopped answering the board).
    pub const LOST: u32 = 0x8000_0000;
}

/// One motor on the board.
#[derive(Debug, Clone)]
pub struct BoardMotor {
    /// Its index in the messages (0–34).
    pub slot: usize,
    /// The motor (its ranges, torque limit, thermal figures, command timeout).
    pub firmware: MitFirmwareConfig,
}

/// How the board is set up.
#[derive(Debug, Clone)]
pub struct BoardConfig {
    /// The motors it drives.
    pub motors: Vec<BoardMotor>,
    /// `LowState` period (2 ms: 500 Hz on a G1).
    pub state_period: Duration,
    /// The robot variant it reports in `mode_machine`.
    pub mode_machine: u8,
    /// Supply voltage each motor reports, V.
    pub supply_voltage: f32,
}

/// What happened to a command the board was given.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandVerdict {
    /// Applied to the motors.
    Accepted,
    /// Its CRC was wrong: ignored.
    BadCrc,
    /// Not a `LowCmd`: ignored.
    Malformed,
    /// A right CRC, but a motor with torque on was sent a value that is not a number (NaN,
    /// infinite): ignored whole, the motors keep their last command (and time out on it).
    NonFinite,
}

/// A fault a test schedules on the board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoardFault {
    /// No `LowState` for this many periods (`None`: from now on).
    SilentState(Option<u32>),
    /// The next this many states go out with a wrong CRC.
    CorruptCrc(u32),
    /// A motor (by slot) stops answering the board: its state freezes, torque is lost, and its
    /// status says so.
    MotorLost(usize),
    /// A motor's winding overheats (status bit, torque off).
    Overheat(usize),
}

/// What the board has seen.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BoardStats {
    /// Commands applied.
    pub accepted: u64,
    /// Commands ignored for their CRC.
    pub bad_crc: u64,
    /// Samples that were not a `LowCmd`.
    pub malformed: u64,
    /// Commands ignored for a value that is not a number.
    pub non_finite: u64,
    /// States published.
    pub states: u64,
}

/// The emulated board.
#[derive(Debug)]
pub struct UnitreeBoard {
    config: BoardConfig,
    motors: Vec<MitMotorFirmware>,
    /// The state each lost motor last reported (frozen).
    frozen: Vec<Option<(f64, f64)>>,
    /// Mode the last accepted command asked for, per motor.
    modes: Vec<u8>,
    next_state: SimInstant,
    silent: Option<Option<u32>>,
    corrupt: u32,
    state: LowState,
    cdr: Vec<u8>,
    /// The sequence number of the state `cdr` holds (written when someone asks for it).
    cdr_of: u64,
    sequence: u64,
    published_at: Option<SimInstant>,
    stats: BoardStats,
}

impl UnitreeBoard {
    /// A board with every motor off; its first state goes out at `start`.
    pub fn new(config: BoardConfig, start: SimInstant) -> Self {
        let motors: Vec<_> = config
            .motors
            .iter()
            .map(|m| MitMotorFirmware::new(m.firmware.clone()))
            .collect();
        let n = motors.len();
        Self {
            motors,
            frozen: vec![None; n],
            modes: vec![0; n],
            next_state: start,
            silent: None,
            corrupt: 0,
            state: LowState {
                mode_machine: config.mode_machine,
                ..LowState::default()
            },
            cdr: Vec::with_capacity(LowState::CDR_LEN),
            cdr_of: 0,
            sequence: 0,
            published_at: None,
            stats: BoardStats::default(),
            config,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &BoardConfig {
        &self.config
    }

    /// Takes a `LowCmd` (its CDR): with a right CRC each motor gets its mode and law (mode 0:
    /// torque off); otherwise nothing changes.
    pub fn receive(&mut self, now: SimInstant, cdr: &[u8]) -> CommandVerdict {
        let Ok(cmd) = LowCmd::read_cdr(cdr) else {
            self.stats.malformed += 1;
            return CommandVerdict::Malformed;
        };
        self.receive_message(now, &cmd)
    }

    /// [`Self::receive`] of the message itself, from a host in the same process (lockstep):
    /// nothing decodes what was never encoded; the CRC is checked all the same.
    pub fn receive_message(&mut self, now: SimInstant, cmd: &LowCmd) -> CommandVerdict {
        if !cmd.crc_ok() {
            self.stats.bad_crc += 1;
            return CommandVerdict::BadCrc;
        }
        let finite =
            |c: &MotorCmd| c.mode == 0 || [c.q, c.dq, c.kp, c.kd, c.tau].iter().all(|v| v.is_finite());
        if !self.config.motors.iter().all(|m| finite(&cmd.motor_cmd[m.slot])) {
            self.stats.non_finite += 1;
            return CommandVerdict::NonFinite;
        }
        self.state.mode_pr = cmd.mode_pr;
        for (k, m) in self.config.motors.iter().enumerate() {
            let c = cmd.motor_cmd[m.slot];
            self.modes[k] = c.mode;
            let law = (c.mode != 0).then_some(MitCommand {
                p: f64::from(c.q),
                v: f64::from(c.dq),
                kp: f64::from(c.kp),
                kd: f64::from(c.kd),
                t: f64::from(c.tau),
            });
            self.motors[k].drive(now, law);
        }
        self.stats.accepted += 1;
        CommandVerdict::Accepted
    }

    /// The motors, in [`BoardConfig::motors`]' order: the mirror ticks each on its joint.
    pub fn motors_mut(&mut self) -> &mut [MitMotorFirmware] {
        &mut self.motors
    }

    /// When the next state is due.
    pub fn next_state(&self) -> SimInstant {
        self.next_state
    }

    /// Forces a fault.
    pub fn inject(&mut self, fault: BoardFault) {
        match fault {
            BoardFault::SilentState(n) => self.silent = Some(n),
            BoardFault::CorruptCrc(n) => self.corrupt = n,
            BoardFault::MotorLost(slot) | BoardFault::Overheat(slot) => {
                let Some(k) = self.config.motors.iter().position(|m| m.slot == slot) else {
                    return;
                };
                let injected = if matches!(fault, BoardFault::MotorLost(_)) {
                    InjectedFaults {
                        silent: true,
                        ..InjectedFaults::default()
                    }
                } else {
                    InjectedFaults {
                        fault: Some(MotorFault::OverTemperature),
                        ..InjectedFaults::default()
                    }
                };
                self.motors[k].inject(injected);
            }
        }
    }

    /// If a state is due at `now`: fills it from the motors' plants (`plant(k)` is motor `k`'s)
    /// and `imu` and seals it ([`Self::state`]; its CDR is written when read,
    /// [`Self::state_cdr`]); returns whether one was published. Allocates nothing.
    pub fn publish(
        &mut self,
        now: SimInstant,
        imu: &ImuState,
        plant: &mut dyn FnMut(usize) -> (f64, f64),
    ) -> bool {
        if now < self.next_state {
            return false;
        }
        while self.next_state <= now {
            self.next_state = self.next_state + self.config.state_period;
        }
        match &mut self.silent {
            Some(None) => return false,
            Some(Some(0)) => self.silent = None,
            Some(Some(n)) => {
                *n -= 1;
                return false;
            }
            None => {}
        }
        let s = &mut self.state;
        // The board's millisecond counter wraps as a u32 does.
        s.tick = (now.as_nanos() / 1_000_000) as u32;
        s.imu_state = *imu;
        for (k, m) in self.config.motors.iter().enumerate() {
            let fw = &self.motors[k];
            let (q, qd) = plant(k);
            let measured = (q - fw.zero_offset(), qd);
            // A lost motor's last report stays in the message.
            let (q, qd) = if fw.silent() {
                *self.frozen[k].get_or_insert(measured)
            } else {
                measured
            };
            let out = &mut s.motor_state[m.slot];
            out.mode = u8::from(fw.enabled()) * self.modes[k].max(1);
            out.q = q as f32;
            out.dq = qd as f32;
            out.ddq = 0.0;
            out.tau_est = if fw.silent() { 0.0 } else { fw.torque() as f32 };
            let winding = fw.temperature();
            let case = fw.config().ambient_c + 0.5 * (winding - fw.config().ambient_c);
            out.temperature = [winding.round() as i16, case.round() as i16];
            out.vol = self.config.supply_voltage;
            out.motorstate = status_bits(fw);
        }
        s.seal();
        if self.corrupt > 0 {
            self.corrupt -= 1;
            s.crc ^= 0xDEAD_BEEF;
        }
        self.sequence += 1;
        self.published_at = Some(now);
        self.stats.states += 1;
        true
    }

    /// The newest state's CDR and its sequence number (0: none yet), encoded on the first read
    /// of each state.
    pub fn state_cdr(&mut self) -> (&[u8], u64) {
        if self.cdr_of != self.sequence {
            self.state.write_cdr(&mut self.cdr);
            self.cdr_of = self.sequence;
        }
        (&self.cdr, self.sequence)
    }

    /// The newest state as sealed (its CRC as sent, right or not) and its sequence number (0:
    /// none yet, the state all zeros).
    pub fn state(&self) -> (&LowState, u64) {
        (&self.state, self.sequence)
    }

    /// When the newest state was published.
    pub fn published_at(&self) -> Option<SimInstant> {
        self.published_at
    }

    /// What the board has seen.
    pub fn stats(&self) -> BoardStats {
        self.stats
    }
}

/// A motor's status word: Unitree's bits for what its firmware reports.
fn status_bits(fw: &MitMotorFirmware) -> u32 {
    if fw.silent() {
        return motor_bits::LOST;
    }
    match fw.fault() {
        MotorFault::None => 0,
        MotorFault::OverTemperature => motor_bits::WINDING_OVERHEAT,
        MotorFault::MosOverTemperature => motor_bits::MOS_OVERHEAT,
        MotorFault::OverCurrent => motor_bits::OVERCURRENT,
        MotorFault::UnderVoltage => motor_bits::UNDERVOLTAGE,
        MotorFault::Encoder => motor_bits::ENCODER,
        MotorFault::CommunicationLost => motor_bits::COMMAND_TIMEOUT,
        _ => motor_bits::OVERCURRENT,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mit::models::find;
    use crate::plant::{InertiaPlant, MotorPlant};

    fn board() -> UnitreeBoard {
        let model = find("AK80-9").unwrap();
        UnitreeBoard::new(
            BoardConfig {
                motors: vec![BoardMotor {
                    slot: 3,
                    firmware: MitFirmwareConfig::new(3, model),
                }],
                state_period: Duration::from_millis(2),
                mode_machine: 5,
                supply_voltage: 58.0,
            },
            SimInstant::ZERO,
        )
    }

    fn command(q: f32, crc_ok: bool) -> Vec<u8> {
        let mut cmd = LowCmd {
            mode_machine: 5,
            ..LowCmd::default()
        };
        cmd.motor_cmd[3] = MotorCmd {
            mode: 1,
            q,
            kp: 20.0,
            kd: 1.0,
            ..MotorCmd::default()
        };
        cmd.seal();
        if !crc_ok {
            cmd.crc ^= 1;
        }
        let mut buf = Vec::new();
        cmd.write_cdr(&mut buf);
        buf
    }

    /// Runs the board and a one-joint plant for `steps` of 1 ms; returns the last state.
    fn run(
        b: &mut UnitreeBoard,
        plant: &mut InertiaPlant,
        t: &mut SimInstant,
        steps: u32,
    ) -> Option<LowState> {
        let dt = Duration::from_millis(1);
        let mut last = None;
        for _ in 0..steps {
            b.motors_mut()[0].tick(*t, dt, plant);
            plant.integrate(dt.as_secs_f64());
            let (q, qd) = (plant.position(), plant.velocity());
            if b.publish(*t, &ImuState::default(), &mut |_| (q, qd)) {
                last = Some(LowState::read_cdr(b.state_cdr().0).unwrap());
            }
            *t = *t + dt;
        }
        last
    }

    #[test]
    fn a_command_with_a_right_crc_moves_the_motor_and_a_wrong_one_is_ignored() {
        let mut b = board();
        let mut plant = InertiaPlant::new(0.02, 0.05, 0.0, 0.0);
        let mut t = SimInstant::ZERO;
        assert_eq!(b.receive(t, &command(0.5, false)), CommandVerdict::BadCrc);
        let s = run(&mut b, &mut plant, &mut t, 200).unwrap();
        assert!(s.crc_ok());
        assert_eq!((s.motor_state[3].mode, s.motor_state[3].q), (0, 0.0), "still off");
        assert_eq!(b.receive(t, &command(0.5, true)), CommandVerdict::Accepted);
        for _ in 0..50 {
            b.receive(t, &command(0.5, true));
            run(&mut b, &mut plant, &mut t, 10);
        }
        let s = run(&mut b, &mut plant, &mut t, 2).unwrap();
        assert_eq!(s.motor_state[3].mode, 1);
        assert!((s.motor_state[3].q - 0.5).abs() < 0.02, "{}", s.motor_state[3].q);
        assert_eq!(s.mode_machine, 5);
        assert_eq!(b.receive(t, b"junk"), CommandVerdict::Malformed);
        // A right CRC over a NaN: ignored whole, the motor holds its last command.
        assert_eq!(b.receive(t, &command(f32::NAN, true)), CommandVerdict::NonFinite);
        let s = run(&mut b, &mut plant, &mut t, 2).unwrap();
        assert!((s.motor_state[3].q - 0.5).abs() < 0.02, "{}", s.motor_state[3].q);
        assert_eq!(
            b.stats(),
            BoardStats {
                accepted: 51,
                bad_crc: 1,
                malformed: 1,
                non_finite: 1,
                states: b.stats().states
            }
        );
        // 500 Hz: one state every 2 ms.
        assert_eq!(b.stats().states, (t.as_nanos() / 1_000_000).div_ceil(2));
    }

    #[test]
    fn faults_silence_the_state_corrupt_its_crc_and_drop_a_motor() {
        let mut b = board();
        let mut plant = InertiaPlant::new(0.02, 0.05, 0.0, 0.0);
        let mut t = SimInstant::ZERO;
        b.inject(BoardFault::SilentState(Some(3)));
        let before = b.stats().states;
        run(&mut b, &mut plant, &mut t, 6);
        assert_eq!(b.stats().states, before, "three periods without a state");
        b.inject(BoardFault::CorruptCrc(1));
        let s = run(&mut b, &mut plant, &mut t, 2).unwrap();
        assert!(!s.crc_ok());
        let s = run(&mut b, &mut plant, &mut t, 2).unwrap();
        assert!(s.crc_ok());
        b.receive(t, &command(0.5, true));
        b.inject(BoardFault::MotorLost(3));
        let s = run(&mut b, &mut plant, &mut t, 20).unwrap();
        assert_eq!(s.motor_state[3].motorstate, motor_bits::LOST);
        assert_eq!(s.motor_state[3].tau_est, 0.0);
    }
}
