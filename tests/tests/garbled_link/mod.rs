//! A link between the loop and a robot that alters what it reads from some read on: garbled
//! readings (a broken encoder, a firmware bug, a foreign publisher, every checksum right), for the
//! whole-path tests of what the loop does with feedback it must not trust.

use std::time::Duration;

use robot_link::{IoError, JointTarget, RobotLink, RobotState, TickClock};

/// What a [`Garbled`] link does to a reading.
pub type Garble = fn(&mut RobotState);

/// `inner`, its readings passed through `garble` from read `from` on (identify's read counts as
/// the first).
#[derive(Debug)]
pub struct Garbled<L> {
    pub inner: L,
    pub reads: u32,
    pub from: u32,
    pub garble: Garble,
}

impl<L: RobotLink> RobotLink for Garbled<L> {
    fn identify(&mut self) -> Result<(), IoError> {
        self.inner.identify()
    }
    fn read(&mut self, state: &mut RobotState) -> Result<(), IoError> {
        self.inner.read(state)?;
        self.reads += 1;
        if self.reads >= self.from {
            (self.garble)(state);
        }
        Ok(())
    }
    fn write(&mut self, targets: &[JointTarget]) -> Result<(), IoError> {
        self.inner.write(targets)
    }
    fn wait_until(&mut self, clock: &mut dyn TickClock, deadline: Duration) -> bool {
        self.inner.wait_until(clock, deadline)
    }
    fn torque_off(&mut self) -> Result<(), IoError> {
        self.inner.torque_off()
    }
    fn set_stale_cycles(&mut self, cycles: u32) {
        self.inner.set_stale_cycles(cycles);
    }
}
