//! A whole calibration run: the procedure on a rig, then the results written beside robot.toml.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use robots::Robot;

use crate::operator::Operator;
use crate::procedure::{CalibrationError, Method, Options, Outcome, Plan, Session};
use crate::rig::Rig;

/// Where a calibration run left its files.
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    /// The new calibration file.
    pub calibration: PathBuf,
    /// The previous one, if there was one.
    pub previous: Option<PathBuf>,
}

/// The robot a calibration rig for `plan` is built from: actuator units ([`crate::raw_robot`]),
/// at the low gains the stop method moves with.
pub fn rig_robot(robot: &Robot, plan: &Plan) -> Robot {
    match &plan.method {
        Method::Jig => crate::raw_robot(robot),
        Method::Stops(o) => crate::raw_robot(&o.low_gain_robot(robot)),
    }
}

/// Runs `plan` on `robot` with `rig` (built from [`rig_robot`]) and, only when every step
/// succeeded, writes `calibration.toml` beside robot.toml: this run's results over what the file
/// held (the previous file kept as `calibration.previous.toml`). The tick log goes to `log` in
/// every case.
#[allow(clippy::too_many_arguments)]
pub fn run_calibration<R: Rig + ?Sized, O: Operator + ?Sized>(
    robot: &Robot,
    rig: &mut R,
    operator: &mut O,
    abort: &AtomicBool,
    plan: &Plan,
    options: Options,
    log: Option<&Path>,
    note: &str,
) -> Result<(Outcome, Written), CalibrationError> {
    let mut session = Session::new(robot, rig, operator, abort, options);
    let outcome = session.calibrate(plan);
    if let Some(Err(e)) = log.map(|path| session.log.write_csv(path)) {
        session.operator().say(&format!("cannot write the tick log: {e}"));
    }
    let outcome = outcome?;
    let path = robots::calibration::path_for(&robot.path);
    let old = robots::calibration::Calibration::read(&path)?;
    let previous = old
        .is_some()
        .then(|| robots::calibration::previous_path_for(&robot.path));
    let calibration = outcome.calibration(note, old).write_beside(&robot.path)?;
    Ok((
        outcome,
        Written {
            calibration,
            previous,
        },
    ))
}
