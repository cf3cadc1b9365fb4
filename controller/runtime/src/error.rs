//! Why a run could not start or continue: one error for the loop and the stages that set it up
//! (reference loading, kinematics, the recording), below all of them so none imports the loop.

use robot_link::{ErrorKind, IoError};

/// Why a run could not start or continue.
#[derive(Debug, thiserror::Error)]
pub enum PlayError {
    /// The buses.
    #[error(transparent)]
    Io(#[from] IoError),
    /// The policy.
    #[error(transparent)]
    Onnx(#[from] policy::onnx::OnnxError),
    /// The policy manifest.
    #[error(transparent)]
    Policy(#[from] policy::PolicyError),
    /// The recording.
    #[error(transparent)]
    Telemetry(#[from] crate::telemetry::TelemetryError),
    /// Forward kinematics of the reference on the robot's model.
    #[error(transparent)]
    Kinematics(#[from] world::KinematicsError),
    /// The clip.
    #[error(transparent)]
    Clip(#[from] crate::clip::ClipError),
    /// The motion a tracking export carries.
    #[error(transparent)]
    Motion(#[from] crate::motion::MotionError),
    /// The inputs of a run do not fit together (reference and policy, model and robot).
    #[error("{0}")]
    Setup(String),
}

impl PlayError {
    /// What kind of failure this is.
    pub fn kind(&self) -> ErrorKind {
        match self {
            Self::Io(e) => e.kind(),
            Self::Onnx(policy::onnx::OnnxError::Runtime(_)) => ErrorKind::Unavailable,
            Self::Onnx(_)
            | Self::Policy(_)
            | Self::Setup(_)
            | Self::Kinematics(_)
            | Self::Clip(_)
            | Self::Motion(_) => ErrorKind::BadInput,
            Self::Telemetry(_) => ErrorKind::Io,
        }
    }
}
