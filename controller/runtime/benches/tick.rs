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
//!    With 2D keypoint references (two views, the fixture policy observing them), and on a
//!    motion generator's plans; and the generator's own step (its worker's latency).
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
use policy::PolicyLayout;
use robots::{Robot, reference_robot_path};

/// The reference robot and the squat as a BeyondMimic-convention export carrying its motion
/// (`.local/fixtures/rd_biped_tracking.onnx`, made by `scripts/setup`), with that motion.
fn tracking_export() -> (Robot, PolicyLayout, Reference) {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let export = test_support::fixtures::fixture("rd_biped_tracking.onnx");
    let mut layout = PolicyLayout::load(&export, &robot).unwrap();
    let squat = reference_robot_path().with_file_name("clips/squat.csv");
    let (reference, _) = controller::reference::load_reference(None, &squat, &mut layout, &robot, 0).unwrap();
    (robot, layout, reference)
}

/// rd-mini and its command-driven fixture, no clip, walking orders in force.
fn command_driven() -> (Robot, PolicyLayout, Reference) {
    let root = test_support::fixtures::workspace_root().join("robots/mini");
    let robot = Robot::load(&root.join("robot.toml")).unwrap();
    let mut layout = PolicyLayout::load(&root.join("policies/stand_walk.toml"), &robot).unwrap();
    layout.set_command(&[0.2, 0.0, 0.4]).unwrap();
    let unused = root.join("unused.csv");
    let (reference, _) =
        controller::reference::load_reference(None, &unused, &mut layout, &robot, 0).unwrap();
    (robot, layout, reference)
}

/// The squat with its 2D keypoint references through rd-biped's two cameras, on the fixture
/// policy that observes them (20 references now and ahead, 10 of the robot's own keypoints).
fn keypoint_references() -> (Robot, PolicyLayout, Reference) {
    let (robot, _, mut reference) = files();
    let root = test_support::fixtures::workspace_root();
    let layout = PolicyLayout::load(
        &root.join("tests/fixtures/policies/keypoint_follower.toml"),
        &robot,
    )
    .unwrap();
    let cameras =
        controller::keypoints::camera::load_cameras(&reference_robot_path().with_file_name("cameras.toml"))
            .unwrap();
    let (names, positions) = controller::keypoints::keypoint_positions(&robot, &reference).unwrap();
    let times: Vec<f64> = (0..reference.len()).map(|k| k as f64 / 50.0).collect();
    let clip = controller::keypoints::project(&cameras, &names, &times, &positions);
    reference.keypoints = Some(
        controller::keypoints::track::KeypointReference::new(&clip, &cameras, 50.0, reference.len()).unwrap(),
    );
    (robot, layout, reference)
}

/// The squat generator's model alone: one step (8 frames in, 3 out, 18 joints), p50/p99.
fn generator_step() -> Summary {
    let model = reference_robot_path().with_file_name("generators/squat_ar.onnx");
    let mut m = policy::onnx::OnnxModel::load_tensors(&model).unwrap();
    // The history, then the command (the intensity).
    let (history, mut next) = (vec![0.1f32; 8 * 18 + 1], vec![0.0f32; 3 * 18]);
    let mut samples = Vec::with_capacity(20_000);
    for _ in 0..20_000 {
        let t0 = Instant::now();
        m.run(&history, &mut next).unwrap();
        samples.push(t0.elapsed());
    }
    Summary::of(&mut samples).unwrap()
}

/// The reference follower tracking what the squat generator produces on its worker thread.
fn generated_reference() -> Summary {
    let (robot, layout, _) = files();
    let generator = controller::generator::Generator::load(
        &reference_robot_path().with_file_name("generators/squat_ar.toml"),
        &robot,
    )
    .unwrap();
    let reference = Reference::hold(&layout.default_q, generator.root(), layout.manifest.rate_hz);
    let default_q = layout.default_q.clone();
    // The follower looks 5 ticks (0.1 s) ahead.
    let (worker, plans) = generator
        .start(
            &default_q,
            controller::generator::GeneratorOptions::default(),
            0.1,
        )
        .unwrap();
    let summary = lockstep_compute_with((robot, layout, reference), |p| p.with_source(plans));
    let stats = worker.finish();
    assert_eq!(stats.failed, 0);
    summary
}

fn lockstep_compute(files: (Robot, PolicyLayout, Reference)) -> Summary {
    lockstep_compute_with(files, |p| p)
}

type MirrorPlayer = controller::player::Player<sim2real::link::LockstepRobot>;

fn lockstep_compute_with(
    (robot, layout, reference): (Robot, PolicyLayout, Reference),
    attach: impl FnOnce(MirrorPlayer) -> MirrorPlayer,
) -> Summary {
    let options = PlayOptions {
        end: EndMode::Loop,
        ..PlayOptions::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let (p, mut clock, world) =
        lockstep_player(robot, layout, reference, options, MirrorConfig::default(), stop).unwrap();
    let mut p = attach(p);
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
    println!(
        "the squat with 2D keypoint references in two views (ref_keypoints + keypoints terms, the \
         robot's 17 keypoints projected and measured every tick): {}",
        lockstep_compute(keypoint_references())
    );
    println!(
        "the reference follower on the squat generator's plans (lock-free read, resampled 30 → 50 Hz, \
         6 frames a tick): {}",
        generated_reference()
    );
    println!(
        "squat generator step on its own (ONNX, 8 × 18 + a command in, 3 × 18 out): {}",
        generator_step()
    );
    let seconds = if quick { 3.0 } else { 60.0 };
    println!(
        "wall clock, {seconds:.0} s over socketcand + pseudo-terminals, tick start lateness: {}",
        wall_jitter(seconds)
    );
}
