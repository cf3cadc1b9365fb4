//! What passes between the robot and whoever drives it: measured state, joint targets, device
//! identities, and the simulator's ground truth where there is one.

/// A joint command in robot order: PD target and feed-forward torque.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JointTarget {
    /// Position target, rad.
    pub q: f64,
    /// Velocity target, rad/s.
    pub qd: f64,
    /// Stiffness, N·m/rad.
    pub kp: f64,
    /// Damping, N·m·s/rad.
    pub kd: f64,
    /// Feed-forward torque, N·m.
    pub tau: f64,
    /// Torque on. Off: the joint is limp.
    pub enabled: bool,
}

/// One IMU sample, in the base's axes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImuSample {
    /// Angular velocity, rad/s.
    pub gyro: [f64; 3],
    /// Specific force, m/s².
    pub accel: [f64; 3],
    /// Orientation `[w, x, y, z]`.
    pub quat: [f64; 4],
    /// When it arrived (the link's time).
    pub at: std::time::Duration,
}

/// IMU samples a read hands over at most (the newest; older ones of a longer gap are dropped).
pub const IMU_HISTORY: usize = 16;

/// The robot's measured state, robot joint order.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotState {
    /// Joint positions, rad.
    pub q: Vec<f64>,
    /// Joint velocities, rad/s.
    pub qd: Vec<f64>,
    /// Joint torques (estimates), N·m.
    pub tau: Vec<f64>,
    /// Consecutive reads without fresh feedback, per joint.
    pub missed: Vec<u32>,
    /// A device reports a fault, per joint (latched by a bus that damped itself for it).
    pub faulted: Vec<bool>,
    /// The joint went silent for [`crate::STALE_CYCLES`] cycles of its bus in a row, and the bus
    /// damped itself: latched until torque goes off, so a tick that reads after the joint came
    /// back still sees it.
    pub stale: Vec<bool>,
    /// How old each joint's sample was when read: since the start of the bus cycle that brought
    /// it.
    pub age: Vec<std::time::Duration>,
    /// IMU angular velocity, rad/s.
    pub gyro: [f64; 3],
    /// IMU specific force, m/s².
    pub accel: [f64; 3],
    /// IMU orientation `[w, x, y, z]`.
    pub quat: [f64; 4],
    /// Consecutive reads without a new IMU sample.
    pub imu_missed: u32,
    /// How old the IMU sample was when read: since it arrived.
    pub imu_age: std::time::Duration,
    /// Every IMU sample that arrived since the previous read, oldest first (at most
    /// [`IMU_HISTORY`]): what a state estimator integrates at the IMU's rate.
    pub imu_samples: Vec<ImuSample>,
    /// Foot switches, robot.toml's `feet` order; empty when the robot has none.
    pub foot_switches: Vec<bool>,
}

impl RobotState {
    /// A state for `n` joints, nothing measured yet.
    pub fn new(n: usize) -> Self {
        Self {
            q: vec![0.0; n],
            qd: vec![0.0; n],
            tau: vec![0.0; n],
            missed: vec![u32::MAX; n],
            faulted: vec![false; n],
            stale: vec![false; n],
            age: vec![std::time::Duration::ZERO; n],
            gyro: [0.0; 3],
            accel: [0.0; 3],
            quat: [1.0, 0.0, 0.0, 0.0],
            imu_missed: u32::MAX,
            imu_age: std::time::Duration::ZERO,
            imu_samples: Vec::with_capacity(IMU_HISTORY),
            foot_switches: Vec::new(),
        }
    }
}

impl RobotState {
    /// Copies `other` into `self` without allocating (both for the same number of joints).
    pub fn copy_from(&mut self, other: &Self) {
        self.q.copy_from_slice(&other.q);
        self.qd.copy_from_slice(&other.qd);
        self.tau.copy_from_slice(&other.tau);
        self.missed.copy_from_slice(&other.missed);
        self.faulted.copy_from_slice(&other.faulted);
        self.stale.copy_from_slice(&other.stale);
        self.age.copy_from_slice(&other.age);
        self.gyro = other.gyro;
        self.accel = other.accel;
        self.quat = other.quat;
        self.imu_missed = other.imu_missed;
        self.imu_age = other.imu_age;
        self.imu_samples.clear();
        self.imu_samples.extend_from_slice(&other.imu_samples);
        self.foot_switches.clear();
        self.foot_switches.extend_from_slice(&other.foot_switches);
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

/// What a simulator knows and a real robot does not: the root pose and velocity, foot contacts.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GroundTruth {
    /// Root pose `[x, y, z, w, qx, qy, qz]`.
    pub root_pose: [f64; 7],
    /// Root linear velocity in the base frame.
    pub base_lin_vel: [f64; 3],
    /// Foot contact flags.
    pub foot_contacts: Vec<bool>,
    /// The simulation itself failed (diverged): nothing it says about the robot holds.
    pub simulation_failed: bool,
    /// How late a mirror served in real time is: its simulation behind the wall clock, or its
    /// threads kept waiting for the CPU (the worst of the last quarter second); its devices answer
    /// that much late. Zero in lockstep.
    pub mirror_behind: std::time::Duration,
}
