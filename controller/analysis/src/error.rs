//! What can go wrong reading runs back, by kind.

use std::path::PathBuf;

/// An analysis failure.
#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    /// A recording or an export cannot be read, or is not what it should be.
    #[error("{}: {message}", file.display())]
    File {
        /// The file.
        file: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A recording cannot be read.
    #[error("{}: {source}", file.display())]
    Recording {
        /// The recording.
        file: PathBuf,
        /// Why.
        source: crate::recording::RecordingError,
    },
    /// The inputs do not fit together (two traces, a trace and a policy).
    #[error("{0}")]
    Mismatch(String),
    /// A clip cannot be used.
    #[error(transparent)]
    Clip(#[from] controller::clip::ClipError),
    /// A policy manifest cannot be used.
    #[error(transparent)]
    Policy(#[from] policy::PolicyError),
    /// Running the loop failed.
    #[error(transparent)]
    Play(#[from] controller::player::PlayError),
    /// The robot's model could not be used.
    #[error(transparent)]
    Kinematics(#[from] world::KinematicsError),
    /// Output could not be written.
    #[error("cannot write {}: {source}", path.display())]
    Write {
        /// The file or folder.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

impl AnalysisError {
    /// `message` about `file`.
    pub fn file(file: &std::path::Path, message: impl std::fmt::Display) -> Self {
        Self::File {
            file: file.to_path_buf(),
            message: message.to_string(),
        }
    }

    /// A failure reading the recording `file`.
    pub fn recording(file: &std::path::Path, source: crate::recording::RecordingError) -> Self {
        Self::Recording {
            file: file.to_path_buf(),
            source,
        }
    }

    /// A failed write of `path`.
    pub fn write(path: &std::path::Path, source: std::io::Error) -> Self {
        Self::Write {
            path: path.to_path_buf(),
            source,
        }
    }
}
