//! Bench: latency of teleoperation, from a tracker packet's arrival to the first bus command that
//! uses it. A recorded CMU session streams as VMC at 72 Hz over UDP on 127.0.0.1; the receiver,
//! the teleoperation worker (resampling, map, IK) and the 50 Hz loop drive the mirror in real time
//! (lockstep, paced by the wall clock). Bound: one control period (20 ms) plus the bus time.
//!
//! Run: `cargo bench -p controller --bench teleop_latency` (20 s; 4 s in the smoke run).

use std::sync::Arc;
use std::sync::Mutex;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use controller::clip::Reference;
use controller::player::{EndMode, PlayOptions, Player};
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
    let seconds = if quick { 4.0 } else { 20.0 };
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
    let (q, root) = (teleop.standby.clone(), teleop.root);
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
        Reference::hold(&q, root, 50.0),
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
    let options = SendOptions {
        seconds: Some(seconds),
        ..SendOptions::default()
    };
    let sender = std::thread::Builder::new()
        .name("vr-send".into())
        .spawn(move || send(&bvh, addr, &options, &AtomicBool::new(false), &mut |_, _| {}).unwrap())
        .unwrap();
    let mut clock = PacedLockstepClock::new(world);
    let summary = player.run(&mut clock).unwrap();
    let packets = sender.join().unwrap();
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
