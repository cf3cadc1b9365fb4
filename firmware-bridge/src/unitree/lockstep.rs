//! The host's end of an emulated board in lockstep: a command reaches the board at the world's
//! present, the newest state is the one the board last published, and waiting steps the world.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use crate::time::SimWorld;

use super::board::UnitreeBoard;
use super::hg::{LowCmd, LowState};
use super::host::{Arrived, LowLevelPort};

/// A simulated world with Unitree boards in it (the mirror).
pub trait UnitreeWorld: SimWorld {
    /// Board number `line`.
    fn board_mut(&mut self, line: usize) -> &mut UnitreeBoard;
}

/// The port of board `line` of a shared world.
#[derive(Debug)]
pub struct LockstepUnitreePort<W> {
    world: Arc<Mutex<W>>,
    line: usize,
    /// The sequence number of the newest state taken.
    seen: u64,
}

impl<W: UnitreeWorld> LockstepUnitreePort<W> {
    /// The port of board `line` of `world`.
    pub fn new(world: Arc<Mutex<W>>, line: usize) -> Self {
        Self { world, line, seen: 0 }
    }
}

fn lock<W>(world: &Mutex<W>) -> MutexGuard<'_, W> {
    world.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl<W: UnitreeWorld + Send + std::fmt::Debug> LowLevelPort for LockstepUnitreePort<W> {
    fn send(&mut self, cdr: &[u8]) -> std::io::Result<()> {
        let line = self.line;
        let mut w = lock(&self.world);
        let now = w.now();
        w.board_mut(line).receive(now, cdr);
        Ok(())
    }

    fn newest_state(&mut self, out: &mut Vec<u8>) -> std::io::Result<bool> {
        let line = self.line;
        let mut w = lock(&self.world);
        let (cdr, sequence) = w.board_mut(line).state_cdr();
        if sequence == self.seen {
            return Ok(false);
        }
        self.seen = sequence;
        out.clear();
        out.extend_from_slice(cdr);
        Ok(true)
    }

    // In one process the messages themselves cross: no CDR is written that no one reads
    // (the CRCs are computed and checked as over the wire).
    fn send_message(&mut self, cmd: &LowCmd, _cdr: &mut Vec<u8>) -> std::io::Result<()> {
        let line = self.line;
        let mut w = lock(&self.world);
        let now = w.now();
        w.board_mut(line).receive_message(now, cmd);
        Ok(())
    }

    fn newest_message(&mut self, out: &mut LowState, _cdr: &mut Vec<u8>) -> std::io::Result<Arrived> {
        let line = self.line;
        let mut w = lock(&self.world);
        let (state, sequence) = w.board_mut(line).state();
        if sequence == self.seen {
            return Ok(Arrived::Nothing);
        }
        self.seen = sequence;
        out.clone_from(state);
        Ok(Arrived::State)
    }

    fn wait_state(&mut self, within: Duration) -> std::io::Result<bool> {
        let line = self.line;
        let mut w = lock(&self.world);
        let deadline = w.now() + within;
        while w.now() < deadline {
            if w.board_mut(line).state().1 != self.seen {
                return Ok(true);
            }
            let next = w.board_mut(line).next_state().min(deadline).max(w.now());
            w.step_until(next);
        }
        Ok(w.board_mut(line).state().1 != self.seen)
    }

    fn state_age(&mut self) -> Option<Duration> {
        let line = self.line;
        let mut w = lock(&self.world);
        let now = w.now();
        w.board_mut(line)
            .published_at()
            .map(|at| now.saturating_since(at))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mit::driver::{JointCommand, MitJointConfig};
    use crate::mit::firmware::MitFirmwareConfig;
    use crate::mit::models::find;
    use crate::plant::{InertiaPlant, MotorPlant};
    use crate::time::SimInstant;
    use crate::unitree::board::{BoardConfig, BoardFault, BoardMotor};
    use crate::unitree::hg::ImuState;
    use crate::unitree::host::HgDriver;

    /// A board driving three motors on inertias, a millisecond a step.
    #[derive(Debug)]
    struct Bench {
        board: UnitreeBoard,
        plants: Vec<InertiaPlant>,
        now: SimInstant,
    }

    impl SimWorld for Bench {
        fn now(&self) -> SimInstant {
            self.now
        }

        fn step_until(&mut self, limit: SimInstant) -> SimInstant {
            let dt = Duration::from_millis(1);
            while self.now + dt <= limit {
                for (m, p) in self.board.motors_mut().iter_mut().zip(&mut self.plants) {
                    m.tick(self.now, dt, p);
                    p.integrate(dt.as_secs_f64());
                }
                self.now = self.now + dt;
                let states: Vec<(f64, f64)> =
                    self.plants.iter().map(|p| (p.position(), p.velocity())).collect();
                self.board
                    .publish(self.now, &ImuState::default(), &mut |k| states[k]);
            }
            self.now
        }
    }

    impl UnitreeWorld for Bench {
        fn board_mut(&mut self, _line: usize) -> &mut UnitreeBoard {
            &mut self.board
        }
    }

    /// The port as a remote board's: bytes only, so every message is encoded and decoded.
    #[derive(Debug)]
    struct OverTheWire(LockstepUnitreePort<Bench>);

    impl LowLevelPort for OverTheWire {
        fn send(&mut self, cdr: &[u8]) -> std::io::Result<()> {
            self.0.send(cdr)
        }
        fn newest_state(&mut self, out: &mut Vec<u8>) -> std::io::Result<bool> {
            self.0.newest_state(out)
        }
        fn wait_state(&mut self, within: Duration) -> std::io::Result<bool> {
            self.0.wait_state(within)
        }
        fn state_age(&mut self) -> Option<Duration> {
            self.0.state_age()
        }
    }

    fn bench() -> Arc<Mutex<Bench>> {
        let model = find("AK80-9").unwrap();
        let motors = [2u8, 7, 11]
            .iter()
            .map(|&slot| BoardMotor {
                slot: usize::from(slot),
                firmware: MitFirmwareConfig::new(slot, model),
            })
            .collect();
        let board = UnitreeBoard::new(
            BoardConfig {
                motors,
                state_period: Duration::from_millis(2),
                mode_machine: 5,
                supply_voltage: 58.0,
            },
            SimInstant::ZERO,
        );
        let plants = (0..3)
            .map(|k: u8| InertiaPlant::new(0.01, 0.05, 0.02, 0.1 * f64::from(k)))
            .collect();
        Arc::new(Mutex::new(Bench {
            board,
            plants,
            now: SimInstant::ZERO,
        }))
    }

    #[test]
    fn in_lockstep_the_messages_themselves_cross_and_every_bit_is_what_the_wire_gives() {
        let model = find("AK80-9").unwrap();
        let joints: Vec<MitJointConfig> = [2u8, 7, 11]
            .iter()
            .map(|&slot| MitJointConfig::new(&format!("j{slot}"), slot, model))
            .collect();
        let period = Duration::from_millis(2);
        let (direct, wire) = (bench(), bench());
        let mut a = HgDriver::new(
            LockstepUnitreePort::new(Arc::clone(&direct), 0),
            joints.clone(),
            period,
        )
        .unwrap();
        let mut b = HgDriver::new(
            OverTheWire(LockstepUnitreePort::new(Arc::clone(&wire), 0)),
            joints,
            period,
        )
        .unwrap();
        for k in 0..400u32 {
            if k == 150 {
                // States with a wrong CRC are refused the same way on both paths.
                for w in [&direct, &wire] {
                    lock(w).board.inject(BoardFault::CorruptCrc(3));
                }
            }
            let t = f64::from(k) * 0.002;
            let commands: Vec<Option<JointCommand>> = (0..3)
                .map(|j| {
                    (k > 20).then(|| JointCommand {
                        q: (3.0 * t + f64::from(j)).sin(),
                        kp: 30.0,
                        kd: 1.0,
                        ..JointCommand::default()
                    })
                })
                .collect();
            a.send(&commands).unwrap();
            b.send(&commands).unwrap();
            for w in [&direct, &wire] {
                let mut w = lock(w);
                let until = w.now + period;
                w.step_until(until);
            }
            assert_eq!(a.receive().unwrap(), b.receive().unwrap(), "cycle {k}");
            assert_eq!(a.state(), b.state(), "cycle {k}");
            assert_eq!(a.feedback(), b.feedback(), "cycle {k}");
        }
        assert_eq!(a.stats(), b.stats());
        assert_eq!(a.stats().bad_crc, 3);
        assert_eq!(lock(&direct).board.stats(), lock(&wire).board.stats());
        // The plants moved: the commands acted.
        assert!(lock(&direct).plants.iter().any(|p| p.velocity().abs() > 0.1));
    }
}
