//! The world stage: where the robot is. Its kinematics through its own model ([`kinematics`]:
//! anchor, bodies, feet and soles, legs, keypoints) and the state estimate from the IMU and the
//! legs ([`estimator`]: base position and velocity, accelerometer bias, feet, contacts), knowing
//! nothing of buses, policies or telemetry.

pub mod estimator;
pub mod kinematics;

pub use kinematics::{KinematicsError, RobotKinematics};
