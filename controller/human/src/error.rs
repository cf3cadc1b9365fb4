//! What can go wrong on the human side, by kind: a malformed motion file, a robot model that lacks
//! what the map names, a map or options that do not fit, a failed user calibration, the network.

use sim2real::model_index::ModelIndexError;
use sim2real::mujoco::MujocoError;

/// A human-side failure.
#[derive(Debug, thiserror::Error)]
pub enum HumanError {
    /// A BVH recording cannot be read or is malformed.
    #[error(transparent)]
    Bvh(#[from] motion::bvh::BvhError),
    /// The robot's model lacks a frame or joint the human side names.
    #[error("{0}")]
    Model(#[from] ModelIndexError),
    /// MuJoCo could not load the robot's model.
    #[error(transparent)]
    Mujoco(#[from] MujocoError),
    /// The retargeting map, the recording and the options do not fit together.
    #[error("{0}")]
    Map(String),
    /// The gamepad subsystem cannot be opened (gilrs's message).
    #[error("cannot open gamepads: {0}")]
    Gamepad(String),
    /// A user's calibration (T-pose) failed.
    #[error("{0}")]
    Calibration(String),
    /// A socket or a thread failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done.
        what: String,
        /// Why it failed.
        source: std::io::Error,
    },
}

impl HumanError {
    /// A map error.
    pub fn map(message: impl Into<String>) -> Self {
        Self::Map(message.into())
    }

    /// An I/O error while doing `what`.
    pub fn io(what: impl Into<String>, source: std::io::Error) -> Self {
        Self::Io {
            what: what.into(),
            source,
        }
    }
}
