//! The realtime controller: the loop that reads the robot through its link, builds the policy's
//! observation, runs the ONNX policy, maps and limits its actions and writes them back.
//!
//! The tick path: [`player`] (the loop and its modes) over [`reference`] (where the reference is
//! this tick), the `policy` crate (the contract, the observation, ONNX inference), [`action`]
//! (action mapping and the governor), [`safety`] (modes, faults) and [`metrics`]; around it [`estop`], [`realtime`], [`telemetry`]
//! (the recording sink) and the inputs: [`clip`] files and live references.

pub mod action;
pub mod clip;
pub mod error;
pub mod estop;
pub mod fk;
pub mod generator;
pub mod histogram;
pub mod keypoints;
mod lifecycle;
pub mod metrics;
pub mod motion;
/// NumPy's NPY/NPZ, as the `motion` crate reads them.
pub use ::motion::npy;
pub mod options;
pub mod player;
pub mod readiness;
pub mod realtime;
pub mod reference;
pub mod safety;
pub mod sim;
pub mod telemetry;
mod world_stage;
