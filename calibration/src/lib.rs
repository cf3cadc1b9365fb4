//! Calibration that cannot break the robot: device identities, joint zero offsets and directions
//! from a jig (torque off), the IMU's gyro bias and mounting from static poses, and a verification
//! that moves to the default pose within low torque and speed limits. Results go to
//! `calibration.toml` beside robot.toml (the previous file is kept), which loading a robot merges.
//!
//! The procedure talks to a [`rig::Rig`] (the robot link and its tick clock: the real bus drivers,
//! on hardware or on the mirror) and to an [`operator::Operator`] (a console on hardware; in the
//! mirror, `sim2real`'s hands clamp the simulated jig and tilt the simulated stand).

pub mod log;
pub mod operator;
pub mod procedure;
pub mod rig;
pub mod run;
pub mod solve;
pub mod stops;
pub mod verify;

pub use procedure::raw_robot;
