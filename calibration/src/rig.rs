//! What a calibration needs from the robot, whatever carries it (hardware buses or a mirror): the
//! robot link and its tick clock, stepped one tick at a time, and the damped safe state.

use std::time::Duration;

use robot_link::{DeviceIdentity, IoError, JointTarget, RobotLink, RobotState, TickClock, message_chain};
use robots::Robot;

/// Why the rig failed. The message carries the whole chain of the bus error: calibration reports
/// it to a person as one line.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    /// A device is missing or is not the configured model; nothing was enabled.
    #[error("identity check failed: {}", message_chain(.0))]
    Identity(IoError),
    /// A bus failed.
    #[error("{}", message_chain(.0))]
    Bus(IoError),
}

/// The robot during calibration: a [`RobotLink`] ticked on a [`TickClock`].
pub trait Rig {
    /// The tick period.
    fn period(&self) -> Duration;
    /// Asks every device who it is; torque stays off everywhere.
    fn identify(&mut self) -> Result<Vec<DeviceIdentity>, RigError>;
    /// Sends `targets` (robot order; `None`: every joint limp), waits for the next tick and reads
    /// into `state`. Returns the time of the reading since the rig started.
    fn tick(&mut self, targets: Option<&[JointTarget]>, state: &mut RobotState)
    -> Result<Duration, RigError>;
    /// The safe state: motors damping (no stiffness), servos limp, then torque off.
    fn damp(&mut self) -> Result<(), RigError>;
}

/// A calibration rig on any robot link: the hardware's buses, or the mirror's in lockstep.
#[derive(Debug)]
pub struct LinkRig<L: RobotLink, C: TickClock> {
    link: L,
    clock: C,
    period: Duration,
    deadline: Duration,
    targets: Vec<JointTarget>,
    damping: Vec<f64>,
    torque_used: bool,
}

impl<L: RobotLink, C: TickClock> LinkRig<L, C> {
    /// A rig for `robot` (the robot `link` was built for) ticking at `period` on `clock`.
    pub fn new(link: L, clock: C, period: Duration, robot: &Robot) -> Self {
        let n = robot.config.joints.len();
        Self {
            link,
            clock,
            period,
            deadline: Duration::ZERO,
            targets: vec![JointTarget::default(); n],
            damping: robot.config.joints.iter().map(|j| j.kd).collect(),
            torque_used: false,
        }
    }

    fn exchange(&mut self, state: &mut RobotState) -> Result<(), RigError> {
        self.link.write(&self.targets).map_err(RigError::Bus)?;
        self.deadline = self.deadline.max(self.clock.elapsed()) + self.period;
        self.link.wait_until(&mut self.clock, self.deadline);
        self.link.read(state).map_err(RigError::Bus)
    }
}

impl<L: RobotLink, C: TickClock> Rig for LinkRig<L, C> {
    fn period(&self) -> Duration {
        self.period
    }

    fn identify(&mut self) -> Result<Vec<DeviceIdentity>, RigError> {
        self.link.identify().map_err(RigError::Identity)?;
        self.link.identities().map_err(RigError::Identity)
    }

    fn tick(
        &mut self,
        targets: Option<&[JointTarget]>,
        state: &mut RobotState,
    ) -> Result<Duration, RigError> {
        match targets {
            Some(t) => {
                self.torque_used = true;
                for (out, t) in self.targets.iter_mut().zip(t) {
                    *out = JointTarget { enabled: true, ..*t };
                }
            }
            None => self.targets.fill(JointTarget::default()),
        }
        self.exchange(state)?;
        Ok(self.clock.elapsed())
    }

    fn damp(&mut self) -> Result<(), RigError> {
        if self.torque_used {
            // Damping for half a second (MIT: kp = 0, kd > 0; servos limp), then torque off.
            for (t, &kd) in self.targets.iter_mut().zip(&self.damping) {
                *t = JointTarget {
                    kd,
                    enabled: true,
                    ..JointTarget::default()
                };
            }
            let mut scratch = RobotState::new(self.targets.len());
            let ticks = (0.5 / self.period.as_secs_f64()).ceil() as usize;
            for _ in 0..ticks {
                if self.exchange(&mut scratch).is_err() {
                    break;
                }
            }
        }
        self.targets.fill(JointTarget::default());
        self.link.torque_off().map_err(RigError::Bus)
    }
}
