//! The robot link: the robot as the controller, calibration and replay see it.
//!
//! - [`state`]: measured state, joint targets, device identities, simulator ground truth;
//! - [`link`]: the [`RobotLink`] trait (identify, read, write, torque off) and its errors;
//! - [`bus_robot`]: [`BusRobot`], every bus of a robot.toml behind one read/write, each bus
//!   cycling at its own rate under the policy: on a schedule in one thread (lockstep,
//!   deterministic) or on [`workers`] (one thread per bus, wall clock);
//! - [`cycle`]: one bus cycle (hold or ramp between policy ticks, the bus damping itself after a
//!   fault, staleness judged per cycle) and its statistics; the IMU line polled at its own rate
//!   (`imu_cycle`);
//! - [`hardware`]: opening the buses robot.toml names;
//! - [`clock`]: the [`TickClock`] a loop waits on.

pub mod bus_robot;
pub mod clock;
pub mod contacts;
pub mod cycle;
pub mod hardware;
mod imu_cycle;
pub mod link;
pub mod state;
mod unitree_bus;
mod workers;

pub use bus_robot::{BusPorts, BusRobot};
pub use clock::{TickClock, WallClock};
pub use cycle::{BusStats, CycleRecord, CycleTimes, MAX_RECORDED_JOINTS, STALE_CYCLES};
pub use link::{ErrorKind, IoError, RobotLink, message_chain};
pub use state::{DeviceIdentity, GroundTruth, IMU_HISTORY, ImuSample, JointTarget, RobotState};
