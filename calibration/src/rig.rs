//! What a calibration needs from the robot, whatever carries it (hardware buses or a mirror):
//! device identities, one tick of commands and readings, and the damped safe state.

use std::time::Duration;

/// A joint command during calibration: PD towards `q`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Target {
    /// Position, rad.
    pub q: f64,
    /// Stiffness, N·m/rad.
    pub kp: f64,
    /// Damping, N·m·s/rad.
    pub kd: f64,
}

/// One tick of readings, robot joint order. Joint values are in the units of the robot the rig
/// was built for: actuator angles for a raw rig (see [`crate::raw_robot`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Time since the rig started.
    pub t: Duration,
    /// Positions, rad.
    pub q: Vec<f64>,
    /// Velocities, rad/s.
    pub qd: Vec<f64>,
    /// Torque estimates, N·m.
    pub tau: Vec<f64>,
    /// Consecutive reads without fresh feedback.
    pub missed: Vec<u32>,
    /// The device reports a fault.
    pub faulted: Vec<bool>,
    /// Angular velocity, rad/s.
    pub gyro: [f64; 3],
    /// Specific force, m/s².
    pub accel: [f64; 3],
    /// The AHRS's attitude `[w, x, y, z]` (its own world frame; yaw drifts).
    pub quat: [f64; 4],
    /// Consecutive reads without a new IMU sample.
    pub imu_missed: u32,
}

impl Sample {
    /// Nothing read yet, `n` joints.
    pub fn new(n: usize) -> Self {
        Self {
            t: Duration::ZERO,
            q: vec![0.0; n],
            qd: vec![0.0; n],
            tau: vec![0.0; n],
            missed: vec![u32::MAX; n],
            faulted: vec![false; n],
            gyro: [0.0; 3],
            accel: [0.0; 3],
            quat: [1.0, 0.0, 0.0, 0.0],
            imu_missed: u32::MAX,
        }
    }
}

/// Who a device said it is.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceIdentity {
    /// Joint it drives.
    pub joint: String,
    /// Bus name.
    pub bus: String,
    /// ID on the bus.
    pub id: u8,
    /// Configured model.
    pub model: String,
    /// What the device answered (model number, reply format).
    pub answer: String,
    /// Firmware version, where the protocol reports one.
    pub firmware: Option<u8>,
    /// Current limit programmed in the device, A, where it has one.
    pub current_limit_a: Option<f64>,
    /// The actuator's torque limit, N·m (actuator side).
    pub torque_limit_nm: f64,
}

/// Why the rig failed.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    /// A device is missing or is not the configured model; nothing was enabled.
    #[error("identity check failed: {0}")]
    Identity(String),
    /// A bus failed.
    #[error("{0}")]
    Bus(String),
}

/// The robot during calibration.
pub trait Rig {
    /// The tick period.
    fn period(&self) -> Duration;
    /// Asks every device who it is; torque stays off everywhere.
    fn identify(&mut self) -> Result<Vec<DeviceIdentity>, RigError>;
    /// Sends `targets` (robot order; `None`: every joint limp), waits for the next tick and reads.
    fn tick(&mut self, targets: Option<&[Target]>, sample: &mut Sample) -> Result<(), RigError>;
    /// The safe state: motors damping (no stiffness), servos limp, then torque off.
    fn damp(&mut self) -> Result<(), RigError>;
}
