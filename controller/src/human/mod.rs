//! The human side: motion capture (BVH), the retargeting map onto the robot, inverse kinematics,
//! and live VR trackers (VMC over OSC/UDP).

pub mod bvh;
pub mod ik;
pub mod osc;
pub mod retarget;
pub mod teleop;
pub mod vmc;
pub mod vr_send;
