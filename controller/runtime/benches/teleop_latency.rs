//! Bench: latency of teleoperation, from a tracker packet's arrival to the first bus command that
//! uses it. A recorded CMU session streams as VMC over UDP on 127.0.0.1; the receiver, the
//! teleoperation worker and the 50 Hz loop drive the mirror in real time (lockstep, paced by the
//! wall clock). Bound: one control period (20 ms) plus the bus time.
//!
//! Three sessions: a headset and two controllers at 72 Hz onto rd-biped's reference follower
//! (resampling, map, arm IK); and, where `../shared/third_party/twist2` is beside the checkout, the
//! whole skeleton at 90 Hz onto TWIST2's G1 (forward kinematics, the retargeting step, the trained
//! tracker) and five points at 90 Hz (headset, controllers, foot trackers: the body estimated,
//! then the same), each looped for 60 s, with its falls and key bodies against the operator.
//!
//! Run: `cargo bench -p controller --bench teleop_latency` (20 s + 2 × 60 s; 4 s + 2 × 6 s in the
//! smoke run).

use std::sync::Arc;
use std::sync::Mutex;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use controller::clip::Reference;
use controller::player::{EndMode, PlayOptions, Player};
use human::body_teleop::Wearing;
use human::teleop::{Teleop, TeleopOptions};
use human::vmc::{Serials, VmcReceiver};
use human::vr_send::{SendOptions, send};
use motion::bvh::Bvh;
use policy::PolicyLayout;
use robots::{Robot, reference_robot_path};
use sim2real::link::{PacedLockstepClock, lockstep_robot};
use sim2real::mirror::Mirror;

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    devices(if quick { 4.0 } else { 20.0 });
    if test_support::fixtures::twist2_dir().is_some() {
        for wearing in [Wearing::WholeBody, Wearing::FivePoint] {
            whole_body(wearing, if quick { 6.0 } else { 60.0 });
        }
    }
}

/// An operator `wearing` a skeleton or five points, onto TWIST2's G1 for `seconds`.
fn whole_body(wearing: Wearing, seconds: f64) {
    let robot =
        Robot::load(&test_support::fixtures::workspace_root().join("robots/g1-twist2/robot.toml")).unwrap();
    let policy = robot.default_policy().unwrap();
    let mut layout = PolicyLayout::load(&policy, &robot).unwrap();
    let model = policy::onnx::OnnxModel::load(&layout.onnx_path).unwrap();
    layout.bind_model(model.inputs(), model.output().1).unwrap();
    let receiver = VmcReceiver::start("127.0.0.1:0".parse().unwrap(), Serials::default()).unwrap();
    let mut teleop = human::body_teleop::start(&robot, &receiver, TeleopOptions::default(), wearing).unwrap();
    let mut reference = Reference::hold(&teleop.standby, teleop.root, 50.0);
    reference.live_bodies = human::retarget::key_bodies(&robot);
    let options = SendOptions {
        seconds: Some(seconds),
        rate_hz: 90.0,
        body: match wearing {
            Wearing::WholeBody => human::vr_send::BodySet::Skeleton,
            Wearing::FivePoint => human::vr_send::BodySet::DevicesAndFeet,
        },
        looped: true,
        ..SendOptions::default()
    };
    let (summary, packets) = session(robot, layout, reference, &mut teleop, &receiver, options);
    let sent = match wearing {
        Wearing::WholeBody => "VMC skeleton",
        Wearing::FivePoint => "five points (headset, controllers, foot trackers; the body estimated)",
    };
    println!(
        "\nwhole-body teleoperation, {seconds:.0} s: {sent} at 90 Hz ({packets} bundles) → retargeting → TWIST2 at 50 Hz → G1 mirror"
    );
    if let Some(latency) = &summary.live_latency {
        println!("tracker arrival → first bus command using it: {latency}");
    }
    println!("fell: {}", if summary.fell { "yes" } else { "no" });
    let each: Vec<String> = summary
        .operator_rmse
        .iter()
        .map(|(b, e)| format!("{b} {:.1}", 100.0 * e))
        .collect();
    println!("key bodies from the operator, cm RMS: {}", each.join(", "));
    drop(teleop);
}

/// Runs `robot` on its mirror in wall clock, the teleoperation's live reference over `reference`,
/// while CMU's traffic wave is sent to the receiver as `options` say; the run's summary and the
/// packets sent.
fn session(
    robot: Robot,
    layout: PolicyLayout,
    reference: Reference,
    teleop: &mut Teleop,
    receiver: &VmcReceiver,
    options: SendOptions,
) -> (controller::player::PlaySummary, u64) {
    let seconds = options.seconds.unwrap_or(4.0);
    let world = Arc::new(Mutex::new(
        Mirror::new(robot.clone(), Default::default()).unwrap(),
    ));
    let io = lockstep_robot(&robot, &world).unwrap();
    let play = PlayOptions {
        end: EndMode::Loop,
        max_ticks: Some((seconds * 50.0) as u64),
        ..PlayOptions::default()
    };
    let mut player = Player::new(
        robot,
        layout,
        reference,
        play,
        io,
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap()
    .with_source(controller::reference::TeleopStream::new(
        teleop.live.take().unwrap(),
    ));
    let bvh = Bvh::load(
        &test_support::fixtures::workspace_root().join("data/mocap/cmu_13_26_direct-traffic-wave.bvh"),
    )
    .unwrap();
    let addr = receiver.local_addr();
    let sender = std::thread::Builder::new()
        .name("vr-send".into())
        .spawn(move || send(&bvh, addr, &options, &AtomicBool::new(false), &mut |_, _| {}).unwrap())
        .unwrap();
    let mut clock = PacedLockstepClock::new(world);
    let summary = player.run(&mut clock).unwrap();
    (summary, sender.join().unwrap())
}

/// A headset and two controllers onto rd-biped's reference follower for `seconds`.
fn devices(seconds: f64) {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let mut layout = PolicyLayout::load(
        &reference_robot_path().with_file_name("policies/reference_follower.toml"),
        &robot,
    )
    .unwrap();
    let model = policy::onnx::OnnxModel::load(&layout.onnx_path).unwrap();
    layout.bind_model(model.inputs(), model.output().1).unwrap();
    let receiver = VmcReceiver::start("127.0.0.1:0".parse().unwrap(), Serials::default()).unwrap();
    let mut teleop = Teleop::start(&robot, &receiver, TeleopOptions::default()).unwrap();
    let reference = Reference::hold(&teleop.standby, teleop.root, 50.0);
    let options = SendOptions {
        seconds: Some(seconds),
        ..SendOptions::default()
    };
    let (summary, packets) = session(robot, layout, reference, &mut teleop, &receiver, options);
    let latency = summary.live_latency.unwrap();
    let bound = Duration::from_millis(20) + summary.io.quantile(0.99);
    println!(
        "teleoperation, {seconds:.0} s: VMC at 72 Hz ({packets} packets) → 50 Hz loop → rd-biped mirror"
    );
    println!("tracker packet arrival → first bus command using it: {latency}");
    println!(
        "bound (one control period + bus p99): {:.1} ms — p99 {}",
        bound.as_secs_f64() * 1e3,
        if latency.quantile(0.99) <= bound {
            "within"
        } else {
            "BEYOND"
        }
    );
    println!("bus I/O per tick: {}", summary.io);
    drop(teleop);
}
