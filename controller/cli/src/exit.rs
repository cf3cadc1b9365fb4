//! Exit statuses: what happened, for scripts and supervisors (documented in `robodeploy --help`).
//!
//! | status | meaning |
//! |---|---|
//! | 0 | finished: the run or command did what it was asked |
//! | 1 | failed for another reason (the message says why) |
//! | 2 | bad input: a file, flag or value is wrong; nothing moved |
//! | 3 | safety stop: a fault (stale feedback, device fault, NaN, tilt or fall, tracking error, overruns, bus failure, a diverging mirror) stopped the robot |
//! | 4 | stopped by the operator: SIGINT/SIGTERM or the e-stop |
//! | 5 | I/O failure: a bus, device or file could not be used |

use std::process::ExitCode;

use controller::metrics::RunOutcome;
use robot_link::ErrorKind;

/// Finished.
pub const FINISHED: u8 = 0;
/// Failed for another reason.
pub const FAILED: u8 = 1;
/// Bad input.
pub const BAD_INPUT: u8 = 2;
/// Safety stop.
pub const SAFETY_STOP: u8 = 3;
/// Stopped by the operator.
pub const OPERATOR_STOP: u8 = 4;
/// I/O failure.
pub const IO_FAILURE: u8 = 5;

/// The status of a run that ended as `outcome`.
pub fn of_outcome(outcome: &RunOutcome) -> ExitCode {
    ExitCode::from(match outcome {
        RunOutcome::Finished => FINISHED,
        RunOutcome::StoppedByOperator { .. } => OPERATOR_STOP,
        RunOutcome::SafetyStop { .. } => SAFETY_STOP,
    })
}

fn of_kind(kind: ErrorKind) -> u8 {
    match kind {
        ErrorKind::BadInput => BAD_INPUT,
        ErrorKind::Io | ErrorKind::Device => IO_FAILURE,
        ErrorKind::Unavailable => FAILED,
    }
}

/// The status of a command that failed with `error`: the first error in its chain whose kind is
/// known decides.
pub fn of_error(error: &anyhow::Error) -> ExitCode {
    ExitCode::from(status_of_error(error))
}

/// [`of_error`] as a number.
pub fn status_of_error(error: &anyhow::Error) -> u8 {
    error.chain().find_map(code_of).unwrap_or(FAILED)
}

/// What a status means, in the words of the table above.
pub fn meaning(status: u8) -> &'static str {
    match status {
        FINISHED => "finished",
        BAD_INPUT => "bad input, nothing moved",
        SAFETY_STOP => "safety stop",
        OPERATOR_STOP => "stopped by the operator",
        IO_FAILURE => "I/O failure",
        _ => "failed",
    }
}

fn code_of(e: &(dyn std::error::Error + 'static)) -> Option<u8> {
    use analysis::AnalysisError as A;
    use calibration::procedure::CalibrationError as C;
    use human::HumanError as H;
    if let Some(e) = e.downcast_ref::<controller::player::PlayError>() {
        return Some(of_kind(e.kind()));
    }
    if let Some(e) = e.downcast_ref::<robot_link::IoError>() {
        return Some(of_kind(e.kind()));
    }
    if let Some(e) = e.downcast_ref::<A>() {
        return Some(match e {
            A::Play(p) => of_kind(p.kind()),
            A::Write { .. } => IO_FAILURE,
            A::File { .. }
            | A::Recording { .. }
            | A::Mismatch(_)
            | A::Kinematics(_)
            | A::Clip(_)
            | A::Policy(_) => BAD_INPUT,
        });
    }
    let bvh = |e: &motion::bvh::BvhError| match e {
        motion::bvh::BvhError::Read { .. } => IO_FAILURE,
        motion::bvh::BvhError::Malformed { .. } => BAD_INPUT,
    };
    if let Some(e) = e.downcast_ref::<motion::bvh::BvhError>() {
        return Some(bvh(e));
    }
    if let Some(e) = e.downcast_ref::<H>() {
        return Some(match e {
            H::Bvh(e) => bvh(e),
            H::Io { .. } => IO_FAILURE,
            H::Gamepad(_) => FAILED,
            H::Model(_) | H::Mujoco(_) | H::Map(_) | H::Calibration(_) => BAD_INPUT,
        });
    }
    if let Some(e) = e.downcast_ref::<policy::onnx::OnnxError>() {
        return Some(match e {
            policy::onnx::OnnxError::Runtime(_) => FAILED,
            _ => BAD_INPUT,
        });
    }
    if let Some(e) = e.downcast_ref::<C>() {
        return Some(match e {
            C::Aborted => OPERATOR_STOP,
            C::Rig(_) | C::Save(_) => IO_FAILURE,
            C::Joint { .. } | C::Imu(_) => SAFETY_STOP,
        });
    }
    let bad_input = e.is::<robots::RobotError>()
        || e.is::<robots::FileError>()
        || e.is::<policy::PolicyError>()
        || e.is::<controller::clip::ClipError>()
        || e.is::<controller::npy::NpyError>()
        || e.is::<sim2real::mirror::MirrorError>()
        || e.is::<sim2real::model_index::ModelIndexError>()
        || e.is::<clap::Error>()
        || e.is::<crate::args::FlagError>();
    if bad_input {
        return Some(BAD_INPUT);
    }
    (e.is::<std::io::Error>() || e.is::<controller::telemetry::TelemetryError>()).then_some(IO_FAILURE)
}
