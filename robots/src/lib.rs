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

/// A file that could not be read, parsed or written, and what was wrong with it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: {message}", path.display())]
pub struct FileError {
    /// The file.
    pub path: std::path::PathBuf,
    /// What is wrong.
    pub message: String,
}

impl FileError {
    /// `message` about `path`.
    pub fn new(path: &std::path::Path, message: impl Into<String>) -> Self {
        Self {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
}

/// The reference robot shipped with the project: `robots/biped/robot.toml`.
pub fn reference_robot_path() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("biped/robot.toml")
}
