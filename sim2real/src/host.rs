//! The host side of a mirror in lockstep, for tests, benches and bench-top tools: the robot link
//! the controller uses ([`crate::link::lockstep_robot`], the real bus drivers on the mirror's
//! ports) holding joint positions with the robot's own gains, one tick at a time.

use std::sync::{Arc, Mutex, PoisonError};

use firmware_bridge::time::SimInstant;
use firmware_bridge::time::SimWorld;
use robot_link::{IoError, JointTarget, RobotState};
use robots::Robot;

use crate::config::MirrorConfig;
use crate::link::{LockstepClock, LockstepRobot, lockstep_robot};
use crate::mirror::{Mirror, MirrorError};

/// Why the host side could not start or tick.
#[derive(Debug, thiserror::Error)]
pub enum HostError {
    /// The mirror could not be built.
    #[error(transparent)]
    Mirror(#[from] MirrorError),
    /// The buses.
    #[error(transparent)]
    Io(#[from] IoError),
}

/// The robot link on a mirror, with its state and targets.
#[derive(Debug)]
pub struct MirrorHost {
    /// The mirror, shared with the ports.
    pub world: Arc<Mutex<Mirror>>,
    link: LockstepRobot,
    clock: LockstepClock,
    start: SimInstant,
    state: RobotState,
    targets: Vec<JointTarget>,
}

impl MirrorHost {
    /// Builds the mirror of `robot` and the link on its buses; identifies every device.
    pub fn start(robot: Robot, config: MirrorConfig) -> Result<Self, HostError> {
        let world = Arc::new(Mutex::new(Mirror::new(robot.clone(), config)?));
        let mut link = lockstep_robot(&robot, &world)?;
        link.identify()?;
        let n = robot.config.joints.len();
        let mut state = RobotState::new(n);
        link.read(&mut state)?;
        let clock = LockstepClock::new(Arc::clone(&world));
        let start = world.lock().unwrap_or_else(PoisonError::into_inner).now();
        Ok(Self {
            world,
            link,
            clock,
            start,
            state,
            targets: vec![JointTarget::default(); n],
        })
    }

    /// One control tick: hands every joint its target `q` (robot order) with the robot's PD
    /// gains, and reads the newest state of every bus and the IMU.
    pub fn command_positions(&mut self, robot: &Robot, q: &[f64]) -> Result<(), HostError> {
        for ((t, j), &q) in self.targets.iter_mut().zip(&robot.config.joints).zip(q) {
            *t = JointTarget {
                q,
                kp: j.kp,
                kd: j.kd,
                enabled: true,
                ..JointTarget::default()
            };
        }
        self.link.write(&self.targets)?;
        self.link.read(&mut self.state)?;
        Ok(())
    }

    /// What the last tick read.
    pub fn state(&self) -> &RobotState {
        &self.state
    }

    /// Runs the mirror until `deadline` (the rest of a control tick), the buses cycling at
    /// their rates on the way.
    pub fn wait_until(&mut self, deadline: SimInstant) {
        let since_start = deadline.saturating_since(self.start);
        self.link.wait_until(&mut self.clock, since_start);
    }

    /// The mirror's clock.
    pub fn now(&self) -> SimInstant {
        self.world.lock().unwrap_or_else(PoisonError::into_inner).now()
    }
}
