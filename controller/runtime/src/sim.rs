//! Runs of the loop on the mirror: in lockstep, served in real time over real wires, or direct
//! (the trainer's actuator law on MuJoCo, no buses).

use std::sync::{Arc, Mutex};

use robots::Robot;
use sim2real::link::{
    DirectRobot, LockstepClock, LockstepRobot, ServedClock, WiredRobot, direct_robot, lockstep_robot,
    serve_locally, wired_robot_with,
};
use sim2real::mirror::Mirror;
use sim2real::serve::ServedMirror;

/// A run on the mirror in lockstep through link `L`: the player, the clock that advances the
/// mirror, and the mirror.
pub type MirrorRun<L> = (crate::player::Player<L>, LockstepClock, Arc<Mutex<Mirror>>);

/// A lockstep run over the robot's buses.
pub type LockstepRun = MirrorRun<LockstepRobot>;

/// A direct run (no buses).
pub type DirectRun = MirrorRun<DirectRobot>;

/// A run on the mirror of `robot` in lockstep: the mirror, its drivers, the player and the clock
/// that advances the mirror between ticks.
pub fn lockstep_player(
    robot: Robot,
    layout: policy::PolicyLayout,
    reference: crate::clip::Reference,
    options: crate::player::PlayOptions,
    mirror: sim2real::config::MirrorConfig,
    stop: Arc<std::sync::atomic::AtomicBool>,
) -> Result<LockstepRun, crate::player::PlayError> {
    let mirror = for_run(mirror, &robot, &options, &reference);
    mirror_run(robot, layout, reference, options, mirror, stop, lockstep_robot)
}

/// The player on a mirror built from `mirror` (already set for the run) through the link
/// `link` makes of it, the harness's hoist wired, and the mirror's clock.
fn mirror_run<L: robot_link::RobotLink>(
    robot: Robot,
    layout: policy::PolicyLayout,
    reference: crate::clip::Reference,
    options: crate::player::PlayOptions,
    mirror: sim2real::config::MirrorConfig,
    stop: Arc<std::sync::atomic::AtomicBool>,
    link: fn(&Robot, &Arc<Mutex<Mirror>>) -> Result<L, robot_link::IoError>,
) -> Result<MirrorRun<L>, crate::player::PlayError> {
    let world =
        Mirror::new(robot.clone(), mirror).map_err(|e| crate::player::PlayError::Setup(e.to_string()))?;
    let hoist = world.harness_hoist();
    let world = Arc::new(Mutex::new(world));
    let io = link(&robot, &world)?;
    let mut player = crate::player::Player::new(robot, layout, reference, options, io, stop)?;
    if let Some(h) = hoist {
        player = player.with_harness_hoist(h);
    }
    Ok((player, LockstepClock::new(Arc::clone(&world)), world))
}

/// A run on a mirror of direct fidelity (the trainer's actuator law on MuJoCo, no buses), in
/// lockstep: `mirror.fidelity` is set to direct whatever it said.
pub fn direct_player(
    robot: Robot,
    layout: policy::PolicyLayout,
    reference: crate::clip::Reference,
    options: crate::player::PlayOptions,
    mirror: sim2real::config::MirrorConfig,
    stop: Arc<std::sync::atomic::AtomicBool>,
) -> Result<DirectRun, crate::player::PlayError> {
    let mut mirror = for_run(mirror, &robot, &options, &reference);
    mirror.fidelity = sim2real::config::Fidelity::Direct;
    mirror_run(robot, layout, reference, options, mirror, stop, direct_robot)
}

/// One lockstep run on the mirror `mirror.fidelity` names (wires or direct), start to end.
pub fn run_on_mirror(
    robot: Robot,
    layout: policy::PolicyLayout,
    reference: crate::clip::Reference,
    options: crate::player::PlayOptions,
    mirror: sim2real::config::MirrorConfig,
    stop: Arc<std::sync::atomic::AtomicBool>,
) -> Result<crate::metrics::PlaySummary, crate::player::PlayError> {
    if mirror.fidelity == sim2real::config::Fidelity::Direct {
        let (mut player, mut clock, _world) = direct_player(robot, layout, reference, options, mirror, stop)?;
        player.run(&mut clock)
    } else {
        let (mut player, mut clock, _world) =
            lockstep_player(robot, layout, reference, options, mirror, stop)?;
        player.run(&mut clock)
    }
}

/// The mirror's settings for a run of `reference`: held until driven, in the harness for a
/// harness start; for a `policy` start the robot stands in the reference's first frame, where a
/// trainer resets a tracking episode (the policy owns the robot from that first tick).
fn for_run(
    mirror: sim2real::config::MirrorConfig,
    robot: &Robot,
    options: &crate::player::PlayOptions,
    reference: &crate::clip::Reference,
) -> sim2real::config::MirrorConfig {
    let start = options.start_mode(robot);
    let mut mirror = mirror.for_run(robot, start);
    if start == robots::StartMode::Policy && mirror.start_joints.is_none() && !reference.is_empty() {
        mirror.start_joints = Some(reference.q[..reference.n].to_vec());
    }
    mirror
}

/// A wired run: the player, the wall clock with the mirror's ground truth, and the served mirror
/// (which stops serving when dropped).
pub type WiredRun = (crate::player::Player<WiredRobot>, ServedClock, ServedMirror);

/// A run on the mirror of `robot` served in real time on loopback, the player connected over
/// socketcand and pseudo-terminals as to hardware, each bus on its own thread (`on_start` runs
/// first on each).
pub fn wired_player(
    robot: Robot,
    layout: policy::PolicyLayout,
    reference: crate::clip::Reference,
    options: crate::player::PlayOptions,
    mirror: sim2real::config::MirrorConfig,
    stop: Arc<std::sync::atomic::AtomicBool>,
    on_start: fn(),
) -> Result<WiredRun, crate::player::PlayError> {
    let mirror = for_run(mirror, &robot, &options, &reference);
    let world =
        Mirror::new(robot.clone(), mirror).map_err(|e| crate::player::PlayError::Setup(e.to_string()))?;
    let hoist = world.harness_hoist();
    let served = serve_locally(world)
        .map_err(|e| crate::player::PlayError::Setup(format!("cannot serve the mirror: {e}")))?;
    let io = wired_robot_with(&robot, &served, on_start)?;
    let mut player = crate::player::Player::new(robot, layout, reference, options, io, stop)?;
    if let Some(h) = hoist {
        player = player.with_harness_hoist(h);
    }
    Ok((player, ServedClock::of(&served), served))
}
