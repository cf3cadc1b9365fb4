//! The whole path in lockstep: policy manifest → ONNX policy → safety governor → real bus drivers →
//! emulated MIT motors, Dynamixel servos and IMU → MuJoCo, and back.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};

use controller::clip::{Clip, Reference};
use controller::player::{PlayOptions, PlaySummary, Player};
use controller::policy::PolicyLayout;
use controller::safety::{Cause, Mode};
use controller::sim::{LockstepClock, LockstepRobot, lockstep_robot};
use firmware_bridge::can::virtual_bus::LockstepCanPort;
use firmware_bridge::dxl::transport::LockstepDxlPort;
use firmware_bridge::serial::LockstepStream;
use robots::{Robot, reference_robot_path};
use sim2real::config::MirrorConfig;
use sim2real::mirror::Mirror;

type MirrorPlayer = Player<LockstepCanPort<Mirror>, LockstepDxlPort<Mirror>, LockstepStream<Mirror>>;

fn biped(file: &str) -> PathBuf {
    reference_robot_path().with_file_name(file)
}

fn player(
    policy: PathBuf,
    clip: PathBuf,
    mirror: MirrorConfig,
    options: PlayOptions,
) -> (MirrorPlayer, LockstepClock, Arc<Mutex<Mirror>>) {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let layout = PolicyLayout::load(&policy, &robot).unwrap();
    let reference =
        Reference::from_clip(&Clip::load(&clip).unwrap(), &robot, layout.manifest.rate_hz).unwrap();
    let world = Arc::new(Mutex::new(Mirror::new(robot.clone(), mirror).unwrap()));
    let io: LockstepRobot = lockstep_robot(&robot, &world).unwrap();
    let p = Player::new(
        robot,
        layout,
        reference,
        options,
        io,
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap();
    (p, LockstepClock::new(Arc::clone(&world)), world)
}

fn follower() -> PathBuf {
    biped("policies/reference_follower.toml")
}

fn modes(s: &PlaySummary) -> Vec<(Mode, Mode)> {
    s.transitions.iter().map(|t| (t.from, t.to)).collect()
}

#[test]
fn the_biped_squats_with_the_reference_follower_and_the_log_shows_the_state_machine() {
    let (mut p, mut clock, _world) = player(
        follower(),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        PlayOptions::default(),
    );
    let s = p.run(&mut clock).unwrap();
    assert!(!s.fell, "{s}");
    assert!(s.joint_rmse.to_degrees() < 3.0, "{s}");
    assert!(s.root_rmse.unwrap() < 0.03, "{s}");
    assert_eq!(
        modes(&s),
        vec![
            (Mode::Off, Mode::Ready),
            (Mode::Ready, Mode::SoftStart),
            (Mode::SoftStart, Mode::Running),
            (Mode::Running, Mode::Stopping),
            (Mode::Stopping, Mode::Damped),
            (Mode::Damped, Mode::Off),
        ],
        "{s}"
    );
    assert_eq!(s.transitions[3].cause, Cause::ClipFinished);
}
