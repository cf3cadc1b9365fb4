//! Robot descriptions: which joints a robot has, on which bus and device each sits, its limits,
//! default pose and gains, as typed data loaded from `robot.toml` beside the robot's MJCF.
//!
//! Loading checks every cross-reference (MJCF joints, bodies, sites and meshes; unique IDs per
//! bus; limits inside what the motor model can do) and fails with the file, the field and the value.

pub mod calibration;
pub mod config;
pub mod drivers;
pub mod mjcf;
pub mod spatial;

pub use config::{
    BodyPair, BusConfig, BusKind, HumanBody, ImuConfig, JointConfig, OrientationCompare, RetargetConfig,
    Robot, RobotConfig, RobotError,
};

/// The reference robot shipped with the project: `robots/biped/robot.toml`.
pub fn reference_robot_path() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("biped/robot.toml")
}
