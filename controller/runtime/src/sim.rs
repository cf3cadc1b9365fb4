//! Runs of the loop on the mirror in lockstep.

use std::sync::{Arc, Mutex};

use robots::Robot;
use sim2real::link::{LockstepClock, LockstepRobot, lockstep_robot};
use sim2real::mirror::Mirror;

/// A lockstep run: the player, the clock that advances the mirror, and the mirror.
pub type LockstepRun = (
    crate::player::Player<LockstepRobot>,
    LockstepClock,
    Arc<Mutex<Mirror>>,
);

/// A run on the mirror of `robot` in lockstep: the mirror, its drivers, the player and the clock
/// that advances the mirror between ticks.
pub fn lockstep_player(
    robot: Robot,
    layout: crate::policy::PolicyLayout,
    reference: crate::clip::Reference,
    options: crate::player::PlayOptions,
    mirror: sim2real::config::MirrorConfig,
    stop: Arc<std::sync::atomic::AtomicBool>,
) -> Result<LockstepRun, crate::player::PlayError> {
    let world =
        Mirror::new(robot.clone(), mirror).map_err(|e| crate::player::PlayError::Setup(e.to_string()))?;
    let world = Arc::new(Mutex::new(world));
    let io = lockstep_robot(&robot, &world)?;
    let player = crate::player::Player::new(robot, layout, reference, options, io, stop)?;
    Ok((player, LockstepClock::new(Arc::clone(&world)), world))
}
