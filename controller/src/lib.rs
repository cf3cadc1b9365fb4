//! The realtime controller: the loop that reads the robot, builds the policy's observation, runs the
//! ONNX policy, limits its commands and writes them to the buses.

pub mod batch;
pub mod calibrate;
pub mod clip;
pub mod compare;
pub mod estop;
pub mod fk;
pub mod hardware;
pub mod human;
pub mod motion_check;
pub mod native;
pub mod npy;
pub mod onnx;
pub mod player;
pub mod policy;
pub mod realtime;
pub mod replay;
pub mod report;
pub mod robot_io;
pub mod safety;
pub mod sim;
pub mod telemetry;

/// Loads a robot model with the pinned MuJoCo (for kinematics inside the controller's tools).
pub(crate) fn sim_model(mjcf: &std::path::Path) -> Result<mujoco_rs::prelude::MjModel, String> {
    sim2real::mujoco::load_model(mjcf).map_err(|e| e.to_string())
}
