//! The human side: the map from a human's body onto the robot's (the
//! retargeting map and a VR user's T-pose calibration), inverse kinematics on the robot's MuJoCo
//! model, offline retargeting, live VR trackers (VMC over OSC/UDP), live references for the control
//! loop (teleoperation, handed over lock-free), and a VR sender that plays a BVH as trackers.

pub mod body_map;
pub mod body_teleop;
pub mod commands;
pub mod error;
pub mod ik;
pub mod live;
pub mod osc;
pub mod retarget;
pub mod skeleton;
pub mod sparse;
pub mod teleop;
pub mod vmc;
pub mod vr_send;

pub use error::HumanError;
