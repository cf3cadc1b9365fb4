//! Bench: the control tick of the reference robot.
//!
//! 1. Tick compute in lockstep: the whole tick (MIT frames encoded/decoded for 12 motors on two
//!    buses, one Dynamixel sync read + sync write for 8 servos, IMU packets decoded, observation,
//!    ONNX inference, governor) minus the time spent inside the mirror (physics, firmware,
//!    wires), p50/p99 over the squat clip. Target: p99 under 100 µs. Again with the squat as a
//!    motion-tracking export (BeyondMimic convention: the motion's frame out of the same call,
//!    the anchor terms through the robot's kinematics, 9 tracked bodies): same target. And
//!    rd-mini (16 Dynamixel servos on one line, touch-sensor foot switches) on its
//!    command-driven fixture with no clip: live commands, gait phase, locomotion metrics.
//! 2. Period jitter in wall-clock mode: the mirror served in real time over socketcand and
//!    pseudo-terminals, the loop on absolute deadlines; how late each tick starts, p50/p99/max
//!    (60 s with `--bench`, 3 s in the smoke run).
//!
//! Run: `cargo bench -p controller --bench tick`

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use controller::player::{EndMode, PlayOptions};
use controller::safety::Mode;
use controller::sim::{lockstep_player, wired_player};
use robot_link::TickClock;
use sim2real::config::MirrorConfig;
use test_support::stats::Summary;

#[path = "common/mod.rs"]
mod common;
use common::files;
use controller::clip::Reference;
use controller::policy::PolicyLayout;
use robots::{Robot, reference_robot_path};

/// The reference robot and the squat as a BeyondMimic-convention export carrying its motion
/// (`.local/fixtures/rd_biped_tracking.onnx`, made by `scripts/setup`), with that motion.
fn tracking_export() -> (Robot, PolicyLayout, Reference) {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let export = test_support::fixtures::fixture("rd_biped_tracking.onnx");
    let mut layout = PolicyLayout::load(&export, &robot).unwrap();
    let squat = reference_robot_path().with_file_name("clips/squat.csv");
    let (reference, _) = controller::motion::load_reference(None, &squat, &mut layout, &robot, 0).unwrap();
    (robot, layout, reference)
}

/// rd-mini and its command-driven fixture, no clip, walking orders in force.
fn command_driven() -> (Robot, PolicyLayout, Reference) {
    let root = test_support::fixtures::workspace_root().join("robots/mini");
    let robot = Robot::load(&root.join("robot.toml")).unwrap();
    let mut layout = PolicyLayout::load(&root.join("policies/stand_walk.toml"), &robot).unwrap();
    layout.set_command(&[0.2, 0.0, 0.4]).unwrap();
    let unused = root.join("unused.csv");
    let (reference, _) = controller::motion::load_reference(None, &unused, &mut layout, &robot, 0).unwrap();
    (robot, layout, reference)
}

fn lockstep_compute((robot, layout, reference): (Robot, PolicyLayout, Reference)) -> Summary {
    let options = PlayOptions {
        end: EndMode::Loop,
        ..PlayOptions::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let (mut p, mut clock, world) =
        lockstep_player(robot, layout, reference, options, MirrorConfig::default(), stop).unwrap();
    p.identify().unwrap();
    let period = Duration::from_millis(20);
    let mut samples = Vec::with_capacity(1000);
    for k in 1..=1100u32 {
        let busy0 = world.lock().unwrap().stats().busy;
        let t0 = Instant::now();
        p.step(&clock).unwrap();
        let total = t0.elapsed();
        let busy = world.lock().unwrap().stats().busy - busy0;
        if k > 100 {
            assert_eq!(p.mode(), Mode::Running);
            samples.push(total.saturating_sub(busy));
        }
        p.wait_until(&mut clock, period * k);
    }
    Summary::of(&mut samples).unwrap()
}

fn wall_jitter(seconds: f64) -> String {
    let (robot, layout, reference) = files();
    let options = PlayOptions {
        end: EndMode::Loop,
        max_ticks: Some((seconds * 50.0) as u64),
        ..PlayOptions::default()
    };
    let mirror = MirrorConfig {
        gantry: true,
        ..MirrorConfig::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let (mut p, mut clock, _served) =
        wired_player(robot, layout, reference, options, mirror, stop, || {}).unwrap();
    let s = p.run(&mut clock).unwrap();
    let _ = clock.elapsed();
    format!("{}\n  overruns {}, bus I/O {}", s.jitter, s.overruns, s.io)
}

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    println!(
        "rd-biped control tick (12 MIT motors on 2 CAN buses, 8 Dynamixel servos, IMU, 127-value observation)"
    );
    println!(
        "tick compute in lockstep, mirror time excluded: {}",
        lockstep_compute(files())
    );
    println!(
        "the squat as a tracking export (116-value observation with time_step, motion out of the call, \
         anchor kinematics): {}",
        lockstep_compute(tracking_export())
    );
    println!(
        "rd-mini on a command-driven policy, no clip (16 servos on one line, 59-value observation, \
         live commands, phase, locomotion metrics): {}",
        lockstep_compute(command_driven())
    );
    let seconds = if quick { 3.0 } else { 60.0 };
    println!(
        "wall clock, {seconds:.0} s over socketcand + pseudo-terminals, tick start lateness: {}",
        wall_jitter(seconds)
    );
}
