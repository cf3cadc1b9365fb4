//! The robot link: the robot as the controller, calibration and replay see it.
//!
//! - [`state`]: measured state, joint targets, device identities, simulator ground truth;
//! - [`link`]: the [`RobotLink`] trait (identify, read, write, torque off) and its errors;
//! - [`bus_robot`]: [`BusRobot`], every bus of a robot.toml behind one read/write, in sequence
//!   (lockstep, deterministic) or on [`workers`] (one thread per bus);
//! - [`hardware`]: opening the buses robot.toml names;
//! - [`clock`]: the [`TickClock`] a loop waits on.

pub mod bus_robot;
pub mod clock;
pub mod hardware;
pub mod link;
pub mod state;
mod workers;

pub use bus_robot::{BusPorts, BusRobot};
pub use clock::{TickClock, WallClock};
pub use link::{ErrorKind, IoError, RobotLink, message_chain};
pub use state::{DeviceIdentity, GroundTruth, JointTarget, RobotState};
