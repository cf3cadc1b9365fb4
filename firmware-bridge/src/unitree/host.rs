//! The host's end of a Unitree board: each cycle one sealed `LowCmd` for every motor the robot
//! uses, and the newest `LowState` taken, its CRC checked, the motors' states and the IMU read out
//! of it. Joint units on this side, motor units in the messages (the MIT joint conversion: the
//! board runs the same impedance law).

use std::time::Duration;

use crate::mit::driver::{JointCommand, MitJointConfig};

use super::board::motor_bits;
use super::hg::{ImuState, LowCmd, LowState, MOTORS, Sealed as _};

/// Where commands go and states come from: DDS on the robot's network, or the mirror's board
/// in lockstep.
pub trait LowLevelPort: Send + std::fmt::Debug {
    /// Sends a command's CDR.
    fn send(&mut self, cdr: &[u8]) -> std::io::Result<()>;
    /// The newest state that arrived since the last call, into `out` (its CDR); whether one did.
    fn newest_state(&mut self, out: &mut Vec<u8>) -> std::io::Result<bool>;
    /// Waits up to `within` for a state to arrive (set-up only: the cycle never waits).
    fn wait_state(&mut self, within: Duration) -> std::io::Result<bool>;
    /// How long ago the newest state arrived, on the port's clock (`None`: none yet).
    fn state_age(&mut self) -> Option<Duration>;

    /// Sends a sealed command: its CDR (written into `cdr`) through [`Self::send`]. A port into
    /// the same process (lockstep) hands over the message itself: nothing decodes what was
    /// never encoded.
    fn send_message(&mut self, cmd: &LowCmd, cdr: &mut Vec<u8>) -> std::io::Result<()> {
        cmd.write_cdr(cdr);
        self.send(cdr)
    }

    /// The newest state that arrived since the last call, decoded into `out` (through `cdr`);
    /// see [`Self::send_message`].
    fn newest_message(&mut self, out: &mut LowState, cdr: &mut Vec<u8>) -> std::io::Result<Arrived> {
        if !self.newest_state(cdr)? {
            return Ok(Arrived::Nothing);
        }
        Ok(match LowState::read_cdr(cdr) {
            Ok(s) => {
                *out = s;
                Arrived::State
            }
            Err(_) => Arrived::Malformed,
        })
    }
}

/// What [`LowLevelPort::newest_message`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Arrived {
    /// No state since the last call.
    Nothing,
    /// A state, in the message given (its CRC not yet checked).
    State,
    /// Bytes that are no `LowState`.
    Malformed,
}

/// One motor's state, in joint units.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HgFeedback {
    /// Angle, rad.
    pub q: f64,
    /// Velocity, rad/s.
    pub qd: f64,
    /// Torque estimate, N·m.
    pub tau: f64,
    /// Winding temperature, °C.
    pub temperature: f64,
    /// Unitree's status bits ([`motor_bits`]).
    pub status: u32,
    /// The board runs the motor (mode ≠ 0).
    pub enabled: bool,
    /// Consecutive cycles without a right state (0: fresh, or the newest under a period old).
    pub missed_cycles: u32,
}

impl HgFeedback {
    /// A status bit that means the motor cannot be trusted or has dropped torque. A command
    /// timeout alone is not one: it clears when commands flow again.
    pub fn faulted(&self) -> bool {
        self.status & !motor_bits::COMMAND_TIMEOUT != 0
    }
}

/// What the driver has seen.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct HgStats {
    /// Commands sent.
    pub commands: u64,
    /// States taken with a right CRC.
    pub states: u64,
    /// States dropped for their CRC.
    pub bad_crc: u64,
    /// Samples that were not a `LowState`.
    pub malformed: u64,
}

/// The driver.
#[derive(Debug)]
pub struct HgDriver<P> {
    port: P,
    /// The link's cycle: the board publishes at this rate too.
    period: Duration,
    joints: Vec<MitJointConfig>,
    cmd: LowCmd,
    cmd_cdr: Vec<u8>,
    state_cdr: Vec<u8>,
    state: LowState,
    /// Where a state that arrives is read, beside the last right one.
    incoming: LowState,
    feedback: Vec<HgFeedback>,
    /// States taken so far (the IMU's sample count).
    fresh: u64,
    /// Receives in a row without a right state.
    nonfresh_run: u32,
    stats: HgStats,
}

/// A joint list the board cannot take.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HgError {
    /// A slot out of the message's range.
    #[error("joint {joint}: motor index {slot} is outside [0, {}]", MOTORS - 1)]
    Slot {
        /// The joint.
        joint: String,
        /// Its index.
        slot: u8,
    },
    /// Two joints on one slot.
    #[error("joints {first} and {second} both drive motor index {slot}")]
    Collision {
        /// The first joint.
        first: String,
        /// The second.
        second: String,
        /// The index.
        slot: u8,
    },
}

impl<P: LowLevelPort> HgDriver<P> {
    /// A driver for `joints` (their `motor_id` is the motor's index in the messages), cycling
    /// every `period` as the board publishes.
    pub fn new(port: P, joints: Vec<MitJointConfig>, period: Duration) -> Result<Self, HgError> {
        let mut owner: [Option<usize>; MOTORS] = [None; MOTORS];
        for (i, j) in joints.iter().enumerate() {
            let slot = usize::from(j.motor_id);
            let Some(o) = owner.get_mut(slot) else {
                return Err(HgError::Slot {
                    joint: j.name.clone(),
                    slot: j.motor_id,
                });
            };
            if let Some(first) = *o {
                return Err(HgError::Collision {
                    first: joints[first].name.clone(),
                    second: j.name.clone(),
                    slot: j.motor_id,
                });
            }
            *o = Some(i);
        }
        let n = joints.len();
        Ok(Self {
            port,
            period,
            joints,
            cmd: LowCmd::default(),
            cmd_cdr: Vec::with_capacity(LowCmd::CDR_LEN),
            state_cdr: Vec::with_capacity(LowState::CDR_LEN),
            state: LowState::default(),
            incoming: LowState::default(),
            feedback: vec![HgFeedback::default(); n],
            fresh: 0,
            nonfresh_run: 0,
            stats: HgStats::default(),
        })
    }

    /// Sends one command: each joint's law (`None`: the motor off), the parallel mechanisms
    /// commanded as pitch and roll (`mode_pr` 0), the robot variant the board reports echoed.
    /// Allocates nothing.
    pub fn send(&mut self, commands: &[Option<JointCommand>]) -> std::io::Result<()> {
        self.cmd.mode_pr = 0;
        self.cmd.mode_machine = self.state.mode_machine;
        for (j, c) in self.joints.iter().zip(commands) {
            let m = &mut self.cmd.motor_cmd[usize::from(j.motor_id)];
            match c {
                Some(c) => {
                    let law = j.to_motor(c);
                    m.mode = 1;
                    m.q = law.p as f32;
                    m.dq = law.v as f32;
                    m.kp = law.kp as f32;
                    m.kd = law.kd as f32;
                    m.tau = law.t as f32;
                }
                None => *m = Default::default(),
            }
        }
        self.cmd.seal();
        self.stats.commands += 1;
        self.port.send_message(&self.cmd, &mut self.cmd_cdr)
    }

    /// Takes the newest state: with a right CRC every joint's feedback and the IMU are fresh.
    /// Without one (none arrived, a wrong CRC) the joints have missed a cycle — unless it is the
    /// first such cycle and the newest state arrived under a period ago: the board publishes on
    /// its own clock at the link's rate, and a cycle that falls just before its next state still
    /// holds one from the last period. Returns whether it was fresh. Allocates nothing.
    pub fn receive(&mut self) -> std::io::Result<bool> {
        let fresh = self.take_state()?;
        if fresh {
            self.fresh += 1;
            self.nonfresh_run = 0;
            for (j, f) in self.joints.iter().zip(&mut self.feedback) {
                let m = &self.state.motor_state[usize::from(j.motor_id)];
                let (q, qd, tau) = j.to_joint(f64::from(m.q), f64::from(m.dq), f64::from(m.tau_est));
                *f = HgFeedback {
                    q,
                    qd,
                    tau,
                    temperature: f64::from(m.temperature[0]),
                    status: m.motorstate,
                    enabled: m.mode != 0,
                    missed_cycles: 0,
                };
            }
        } else {
            self.nonfresh_run = self.nonfresh_run.saturating_add(1);
            // The first cycle without a new state, while the newest is under a period old, is a
            // phase slip against the board's clock, not a miss.
            let slip = self.nonfresh_run == 1 && self.port.state_age().is_some_and(|age| age < self.period);
            let missed = if slip { 0 } else { self.nonfresh_run };
            for f in &mut self.feedback {
                f.missed_cycles = missed;
            }
        }
        Ok(fresh)
    }

    /// Takes the newest state that arrived, if one did and its CRC is right.
    fn take_state(&mut self) -> std::io::Result<bool> {
        // Read beside the last right state, which stays if this one is wrong.
        Ok(
            match self
                .port
                .newest_message(&mut self.incoming, &mut self.state_cdr)?
            {
                Arrived::Nothing => false,
                Arrived::Malformed => {
                    self.stats.malformed += 1;
                    false
                }
                Arrived::State if !self.incoming.crc_ok() => {
                    self.stats.bad_crc += 1;
                    false
                }
                Arrived::State => {
                    std::mem::swap(&mut self.state, &mut self.incoming);
                    self.stats.states += 1;
                    true
                }
            },
        )
    }

    /// Waits up to `within` for the first right state (set-up).
    pub fn wait_first(&mut self, within: Duration) -> std::io::Result<bool> {
        let deadline = within;
        let mut waited = Duration::ZERO;
        let step = Duration::from_millis(2);
        while waited < deadline {
            if self.receive()? {
                return Ok(true);
            }
            self.port.wait_state(step)?;
            waited += step;
        }
        self.receive()
    }

    /// Each joint's newest feedback.
    pub fn feedback(&self) -> &[HgFeedback] {
        &self.feedback
    }

    /// The joints.
    pub fn joints(&self) -> &[MitJointConfig] {
        &self.joints
    }

    /// The IMU of the newest right state, and how many right states there were.
    pub fn imu(&self) -> (&ImuState, u64) {
        (&self.state.imu_state, self.fresh)
    }

    /// The newest right state.
    pub fn state(&self) -> &LowState {
        &self.state
    }

    /// What the driver has seen.
    pub fn stats(&self) -> HgStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;

    use super::*;
    use crate::mit::models::find;

    /// A port whose cycles are scripted: a new state or none, and the newest one's age.
    #[derive(Debug)]
    struct Script {
        state: Vec<u8>,
        cycles: VecDeque<(bool, Duration)>,
        age: Duration,
    }

    impl LowLevelPort for Script {
        fn send(&mut self, _: &[u8]) -> std::io::Result<()> {
            Ok(())
        }
        fn newest_state(&mut self, out: &mut Vec<u8>) -> std::io::Result<bool> {
            let (new, age) = self.cycles.pop_front().unwrap_or((false, Duration::from_secs(1)));
            self.age = age;
            out.clone_from(&self.state);
            Ok(new)
        }
        fn wait_state(&mut self, _: Duration) -> std::io::Result<bool> {
            Ok(true)
        }
        fn state_age(&mut self) -> Option<Duration> {
            Some(self.age)
        }
    }

    #[test]
    fn a_cycle_just_before_the_boards_next_state_is_no_miss_but_a_second_without_one_is() {
        let mut state = LowState::default();
        state.seal();
        let mut cdr = Vec::new();
        state.write_cdr(&mut cdr);
        let ms = Duration::from_micros;
        let cycles = [
            (true, ms(100)),
            (false, ms(1_900)), // the board's next state is a hair late: a slip
            (true, ms(50)),
            (false, ms(2_100)), // over a period old: a miss
            (false, ms(4_100)), // and another
            (true, ms(10)),
        ];
        let joints = vec![MitJointConfig::new("knee", 3, find("AK80-9").unwrap())];
        let port = Script {
            state: cdr,
            cycles: cycles.into(),
            age: Duration::ZERO,
        };
        let mut d = HgDriver::new(port, joints, Duration::from_millis(2)).unwrap();
        let missed: Vec<u32> = (0..6)
            .map(|_| {
                d.receive().unwrap();
                d.feedback()[0].missed_cycles
            })
            .collect();
        assert_eq!(missed, [0, 0, 0, 1, 2, 0]);
    }

    #[test]
    fn two_joints_on_one_motor_index_or_an_index_past_the_message_are_refused() {
        let port = || Script {
            state: Vec::new(),
            cycles: VecDeque::new(),
            age: Duration::ZERO,
        };
        let m = find("AK80-9").unwrap();
        let j = |name: &str, id| MitJointConfig::new(name, id, m);
        let period = Duration::from_millis(2);
        assert_eq!(
            HgDriver::new(port(), vec![j("a", 4), j("b", 4)], period).unwrap_err(),
            HgError::Collision {
                first: "a".into(),
                second: "b".into(),
                slot: 4
            }
        );
        assert_eq!(
            HgDriver::new(port(), vec![j("a", 35)], period).unwrap_err(),
            HgError::Slot {
                joint: "a".into(),
                slot: 35
            }
        );
    }
}
