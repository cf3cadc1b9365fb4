//! Robot descriptions: which joints a robot has, on which bus and device each sits, its limits,
//! default pose and gains, as typed data loaded from `robot.toml` beside the robot's MJCF.
//!
//! Loading checks every cross-reference (MJCF joints, bodies, sites and meshes; unique IDs per
//! bus; limits inside what the motor model can do) and fails with the file, the field and the value.

pub mod actuators;
pub mod calibration;
pub mod config;
pub mod drivers;
pub mod estimator;
pub mod locate;
pub mod mjcf;
pub mod spatial;

pub use actuators::{ActuatorGroup, ActuatorModel, ActuatorOf, TorqueHold};
pub use config::{
    BodyPair, BusConfig, BusKind, BusTiming, FrictionCone, GainsOutOfRange, HarnessConfig, HumanBody,
    IMU_SENSOR_KINDS, ImuConfig, ImuSensorNames, Integrator, Interpolation, JointConfig, JointDynamics,
    JointDynamicsOf, KeypointFrame, MAX_HARNESS_LIFT_M, MitModelConfig, OrientationCompare, PositionTargets,
    RetargetConfig, Robot, RobotConfig, RobotError, SafetyConfig, SimConfig, Solver, StageWeights,
    StartConfig, StartMode, TrackingRule, default_command_timeout, matches_pattern,
};
pub use estimator::{EstimatorConfig, FilterKind};

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
    pub fn new(path: &std::path::Path, message: impl std::fmt::Display) -> Self {
        Self {
            path: path.to_path_buf(),
            message: message.to_string(),
        }
    }
}

/// Largest text file the project reads (robot and policy files, clips, motion capture), bytes.
pub const MAX_TEXT_FILE_BYTES: u64 = 256 << 20;

/// Reads a text input file: refused unless it is a regular file of at most
/// [`MAX_TEXT_FILE_BYTES`] (a device such as `/dev/zero`, a folder or a FIFO would hang or exhaust
/// memory), and valid UTF-8. The error says what is wrong, without the path (callers name it).
pub fn read_text(path: &std::path::Path) -> Result<String, ReadError> {
    check_regular_file(path)?;
    std::fs::read_to_string(path).map_err(ReadError::Unreadable)
}

/// Refuses anything but a regular file of at most [`MAX_TEXT_FILE_BYTES`].
pub fn check_regular_file(path: &std::path::Path) -> Result<(), ReadError> {
    let meta = std::fs::metadata(path).map_err(ReadError::Unreadable)?;
    if !meta.is_file() {
        return Err(ReadError::NotRegular);
    }
    if meta.len() > MAX_TEXT_FILE_BYTES {
        return Err(ReadError::TooLarge { bytes: meta.len() });
    }
    Ok(())
}

/// Why an input file was not read (the path is the caller's to name).
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The system refused (missing, no permission) or the text is not UTF-8.
    #[error("cannot read: {0}")]
    Unreadable(std::io::Error),
    /// A folder, device or pipe.
    #[error("not a regular file")]
    NotRegular,
    /// Larger than [`MAX_TEXT_FILE_BYTES`].
    #[error("{bytes} bytes: larger than {MAX_TEXT_FILE_BYTES}")]
    TooLarge {
        /// The file's size.
        bytes: u64,
    },
}

/// A number as a person reads it in an error: plain when ordinary, in exponent form when huge or
/// tiny (`1e308`, not 309 digits).
pub fn num(v: f64) -> String {
    if v != 0.0 && !(1e-3..1e6).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// The reference robot shipped with the project: `robots/biped/robot.toml`.
pub fn reference_robot_path() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("biped/robot.toml")
}
