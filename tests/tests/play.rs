//! The whole path in lockstep: policy manifest → ONNX policy → safety governor → real bus drivers →
//! emulated MIT motors, Dynamixel servos and IMU → MuJoCo, and back.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use controller::clip::{Clip, Reference};
use controller::player::{PlayOptions, PlaySummary, Player};
use controller::safety::{Cause, Mode};
use controller::sim::lockstep_player;
use policy::PolicyLayout;
use robots::{Robot, reference_robot_path};
use sim2real::config::MirrorConfig;
use sim2real::link::LockstepClock;
use sim2real::mirror::Mirror;

mod common;
mod garbled_link;
mod robstride_biped;

#[global_allocator]
static ALLOC: test_support::alloc::CountingAllocator = test_support::alloc::CountingAllocator;

type MirrorPlayer = Player<sim2real::link::LockstepRobot>;

fn biped(file: &str) -> PathBuf {
    reference_robot_path().with_file_name(file)
}

fn player(
    policy: PathBuf,
    clip: PathBuf,
    mirror: MirrorConfig,
    options: PlayOptions,
) -> (MirrorPlayer, LockstepClock, Arc<Mutex<Mirror>>) {
    player_on(
        Robot::load(&reference_robot_path()).unwrap(),
        policy,
        clip,
        mirror,
        options,
    )
}

/// [`player`] on `robot` (rd-biped or a variant of its file).
fn player_on(
    robot: Robot,
    policy: PathBuf,
    clip: PathBuf,
    mirror: MirrorConfig,
    options: PlayOptions,
) -> (MirrorPlayer, LockstepClock, Arc<Mutex<Mirror>>) {
    let layout = PolicyLayout::load(&policy, &robot).unwrap();
    let reference =
        Reference::from_clip(&Clip::load(&clip).unwrap(), &robot, layout.manifest.rate_hz).unwrap();
    lockstep_player(
        robot,
        layout,
        reference,
        options,
        mirror,
        Arc::new(AtomicBool::new(false)),
    )
    .unwrap()
}

/// Steps `p` through the 20 ms ticks `ticks` (1-based: tick k ends at k × 20 ms), the buses
/// cycling in between.
fn run_ticks(p: &mut MirrorPlayer, clock: &mut LockstepClock, ticks: std::ops::RangeInclusive<u32>) {
    let period = Duration::from_millis(20);
    for k in ticks {
        p.step(clock).unwrap();
        p.wait_until(clock, period * k);
    }
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

#[test]
fn the_biped_with_its_left_leg_on_robstride_motors_squats_as_well() {
    let text = std::fs::read_to_string(reference_robot_path()).unwrap();
    let swapped = robstride_biped::left_leg_on_robstride(&text);
    let robot = Robot::from_str(&reference_robot_path(), &swapped).unwrap();
    let family = |name: &str| {
        let j = robot.config.joints.iter().find(|j| j.name == name).unwrap();
        robot.mit_model(&j.model).unwrap().family
    };
    use firmware_bridge::mit::models::MotorFamily;
    assert_eq!(family("left_knee"), MotorFamily::Robstride);
    assert_eq!(family("right_knee"), MotorFamily::Cubemars);
    // `calibrate identify`'s question: the Robstrides give their unique ID and torque limit.
    {
        let world = Arc::new(Mutex::new(
            Mirror::new(robot.clone(), MirrorConfig::default()).unwrap(),
        ));
        let mut link = sim2real::link::lockstep_robot(&robot, &world).unwrap();
        link.identify().unwrap();
        let ids = link.identities().unwrap();
        let knee = ids.iter().find(|d| d.joint == "left_knee").unwrap();
        assert!(knee.answer.starts_with("RS03 uid 52530000"), "{knee:?}");
        // The joint's 40 N·m limit, written into the motor's limit_torque (60 N·m from the
        // factory) when the bus was identified: the motor's own loop holds it between commands.
        assert_eq!(knee.torque_limit_nm, 40.0);
        let right = ids.iter().find(|d| d.joint == "right_knee").unwrap();
        assert!(right.answer.starts_with("AK10-9 reply from"), "{right:?}");
    }
    let (mut p, mut clock, world) = player_on(
        robot,
        follower(),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        PlayOptions::default(),
    );
    let s = p.run(&mut clock).unwrap();
    assert!(!s.fell, "{s}");
    assert!(s.joint_rmse.to_degrees() < 3.0, "{s}");
    assert_eq!(s.transitions[3].cause, Cause::ClipFinished, "{s}");
    // The left leg's motors ran the factory protocol and answered every tick's frame.
    let mut w = world.lock().unwrap();
    let knee = w
        .robot()
        .config
        .joints
        .iter()
        .position(|j| j.name == "left_knee")
        .unwrap();
    let ticks = s.ticks;
    let motor = w.motor_mut(knee).unwrap();
    assert_eq!(motor.config().model.family, MotorFamily::Robstride);
    assert!(
        motor.frames_answered() >= ticks,
        "{} frames for {ticks} ticks",
        motor.frames_answered()
    );
}

fn transition(s: &PlaySummary, to: Mode) -> Option<&controller::safety::Transition> {
    s.transitions.iter().find(|t| t.to == to)
}

#[test]
fn a_servo_that_vanishes_between_ticks_is_damped_within_two_bus_cycles_and_the_rest_within_a_tick() {
    use robot_link::RobotLink;
    use sim2real::config::{FaultKind, ScheduledFault};
    // 7 ms after tick 150's instant: between two policy ticks, inside a Dynamixel cycle.
    let vanish = Duration::from_millis(3007);
    let mirror = MirrorConfig {
        faults: vec![ScheduledFault {
            at_s: vanish.as_secs_f64(),
            joint: "left_elbow".into(),
            fault: FaultKind::Vanish,
        }],
        ..MirrorConfig::default()
    };
    let (mut p, mut clock, world) = player(
        follower(),
        biped("clips/wave_and_look.csv"),
        mirror,
        PlayOptions::default(),
    );
    let s = p.run(&mut clock).unwrap();
    // Link time (the clock's) to mirror time (the fault plan's).
    use firmware_bridge::time::SimWorld;
    use robot_link::TickClock;
    let mirror_now = world
        .lock()
        .unwrap()
        .now()
        .saturating_since(firmware_bridge::time::SimInstant::ZERO);
    let offset = mirror_now - clock.elapsed();
    let robot = p.robot().clone();
    let dxl = p.link().bus_names().iter().position(|n| n == "dxl0").unwrap();
    let stats = p.link().bus_stats()[dxl];
    let period = robot.bus_timing("dxl0").unwrap().period;
    assert_eq!(period, Duration::from_millis(10));
    // The first two cycles that start after the vanish get no reply; the second damps its bus
    // (detected at its finish), and the very next cycle sends damping.
    let detected = stats.damped_at.expect("the bus damped itself") + offset;
    assert!(detected > vanish, "{detected:?}");
    assert!(
        detected - vanish <= period * 2,
        "detected {:?} after the vanish",
        detected - vanish
    );
    let cycle = stats.damped_at_cycle.unwrap();
    assert_eq!(stats.damping_sent_at_cycle, Some(cycle + 1));
    // The loop damps everything at its next tick, straight from Running (no hold).
    let damped = transition(&s, Mode::Damped).expect("damping");
    assert_eq!(damped.from, Mode::Running, "{s}");
    assert!(
        matches!(damped.cause, Cause::StaleFeedback { joint: 14, .. }),
        "{s}"
    );
    let tick = Duration::from_millis(20);
    let damped_at = tick * damped.tick as u32 + offset;
    assert!(damped_at > detected, "{s}");
    assert!(
        damped_at - detected <= tick,
        "the loop damped {:?} after the bus",
        damped_at - detected
    );
    assert_eq!(s.transitions.last().unwrap().to, Mode::Off);
}

#[test]
fn a_nan_action_leads_to_the_safe_state() {
    let dir = std::env::temp_dir().join(format!("play-nan-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let onnx = test_support::fixtures::fixture("nan_after_half_ramp.onnx");
    let manifest = std::fs::read_to_string(follower()).unwrap().replace(
        "onnx = \"reference_follower.onnx\"",
        &format!("onnx = {:?}", onnx.display().to_string()),
    );
    std::fs::write(dir.join("nan.toml"), manifest).unwrap();
    let (mut p, mut clock, _w) = player(
        dir.join("nan.toml"),
        biped("clips/squat.csv"),
        MirrorConfig {
            gantry: true,
            ..MirrorConfig::default()
        },
        PlayOptions::default(),
    );
    let s = p.run(&mut clock).unwrap();
    let stop = transition(&s, Mode::Stopping).expect("a stop");
    assert_eq!(stop.cause, Cause::NonFinite { what: "action" }, "{s}");
    // ψ passes 0.5 half-way through the 1.5 s ramp, which starts after the 1 s soft start.
    assert!((85..=90).contains(&stop.tick), "{s}");
    assert!(transition(&s, Mode::Damped).unwrap().tick <= stop.tick + 2);
    // Every target sent stayed finite.
    assert!(p.targets().iter().all(|t| t.q.is_finite() && t.kp.is_finite()));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_clip_beyond_the_limits_is_refused_with_its_first_bad_frame() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let text = std::fs::read_to_string(biped("clips/squat.csv")).unwrap();
    // Push the left knee past its 2.2 rad limit from t = 1.0 s on.
    let mut out = String::new();
    for line in text.lines() {
        let mut cells: Vec<String> = line.split(',').map(str::to_owned).collect();
        if let Ok(t) = cells[0].parse::<f64>()
            && t >= 1.0
        {
            cells[11] = "2.5".into();
        }
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    let path = std::env::temp_dir().join(format!("bad-clip-{}.csv", std::process::id()));
    std::fs::write(&path, out).unwrap();
    let e = Reference::from_clip(&Clip::load(&path).unwrap(), &robot, 50.0)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("t = 1.000 s (tick 50): left_knee = 2.500 rad is outside its limits [0, 2.2]"),
        "{e}"
    );
    std::fs::remove_file(&path).unwrap();
}

#[test]
fn a_stop_request_soft_stops_through_blend_and_damping() {
    let options = PlayOptions {
        end: controller::player::EndMode::Loop,
        ..PlayOptions::default()
    };
    let (mut p, mut clock, _w) = player(
        follower(),
        biped("clips/wave_and_look.csv"),
        MirrorConfig::default(),
        options,
    );
    p.identify().unwrap();
    let period = Duration::from_millis(20);
    for k in 1..=200u32 {
        if k == 150 {
            p.request_stop();
        }
        p.step(&clock).unwrap();
        p.wait_until(&mut clock, period * k);
    }
    let t = p.transitions();
    let stop = t.iter().find(|t| t.to == Mode::Stopping).unwrap();
    assert_eq!((stop.cause, stop.tick), (Cause::StopRequested, 149));
    let damped = t.iter().find(|t| t.to == Mode::Damped).unwrap();
    // Soft: the policy settles the robot for its 1 s (the reference blends to the standing pose)
    // before damping.
    assert_eq!(damped.tick - stop.tick, 50);
}

#[test]
fn a_steady_state_tick_allocates_nothing() {
    use test_support::alloc::count_allocations;
    let (p, mut clock, _w) = player(
        follower(),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        PlayOptions::default(),
    );
    // Recording too: the loop's side of telemetry is a copy into a preallocated ring.
    let path = std::env::temp_dir().join(format!("alloc-{}.mcap", std::process::id()));
    let names: Vec<String> = (0..20).map(|i| format!("j{i}")).collect();
    let sink = controller::telemetry::TelemetrySink::start(
        &path,
        256,
        controller::telemetry::Backpressure::Drop,
        &controller::telemetry::RecordingInfo {
            joint_names: names.clone(),
            root_frame: "pelvis".into(),
            // The whole observation too, through the buffers made here.
            observation_len: p.recording_info().observation_len,
            ..Default::default()
        },
    )
    .unwrap();
    let mut p = p.with_telemetry(sink);
    p.identify().unwrap();
    run_ticks(&mut p, &mut clock, 1..=80u32);
    assert_eq!(p.mode(), Mode::Running);
    let (_, stats) = count_allocations(|| {
        run_ticks(&mut p, &mut clock, 81..=180u32);
    });
    assert_eq!(p.mode(), Mode::Running);
    assert!(stats.is_zero(), "{stats:?}");
    let _ = std::fs::remove_file(&path);
}

#[test]
fn a_steady_state_tick_over_real_wires_allocates_nothing_on_the_loop_or_the_bus_threads() {
    use test_support::alloc::{count_allocations, watch_this_thread, watched_heap_ops};
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let layout = PolicyLayout::load(&follower(), &robot).unwrap();
    let clip = Clip::load(&biped("clips/squat.csv")).unwrap();
    let reference = Reference::from_clip(&clip, &robot, layout.manifest.rate_hz).unwrap();
    // The run must stay in Running on a busy machine too: what is measured is allocation, so
    // late replies over the pseudo-terminals are tolerated here (their safety is tested elsewhere).
    let options = PlayOptions {
        end: controller::player::EndMode::Loop,
        limits: controller::safety::SafetyLimits {
            stale_cycles: 1000,
            overruns: 1000,
            tracking_ticks: 1000,
            ..Default::default()
        },
        ..PlayOptions::default()
    };
    let mirror = MirrorConfig {
        gantry: true,
        ..MirrorConfig::default()
    };
    // Each bus on its own thread, every heap operation there counted.
    let stop = Arc::new(AtomicBool::new(false));
    let (mut p, mut clock, _served) =
        controller::sim::wired_player(robot, layout, reference, options, mirror, stop, watch_this_thread)
            .unwrap();
    p.identify().unwrap();
    let period = Duration::from_millis(20);
    let mut tick = |p: &mut Player<sim2real::link::WiredRobot>| {
        p.step(&clock).unwrap();
        p.wait_until(&mut clock, period * p.ticks() as u32);
    };
    while p.mode() != Mode::Running {
        tick(&mut p);
        assert!(p.ticks() < 200, "never reached Running: {:?}", p.transitions());
    }
    for _ in 0..20 {
        tick(&mut p);
    }
    let before = watched_heap_ops();
    let (_, stats) = count_allocations(|| {
        for _ in 0..100 {
            tick(&mut p);
        }
    });
    let on_bus_threads = watched_heap_ops() - before;
    assert_eq!(p.mode(), Mode::Running, "{:?}", p.transitions());
    assert!(
        stats.is_zero() && on_bus_threads == 0,
        "loop thread: {stats:?}; heap operations on the bus threads: {on_bus_threads}"
    );
}

#[test]
fn each_mit_motor_gets_one_round_trip_per_bus_cycle_at_the_bus_rate() {
    let (mut p, mut clock, world) = player(
        follower(),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        PlayOptions::default(),
    );
    p.identify().unwrap();
    let period = Duration::from_millis(20);
    let frames = |w: &Arc<Mutex<Mirror>>| -> Vec<(String, usize, u64)> {
        let w = w.lock().unwrap();
        let robot = w.robot();
        robot
            .config
            .buses
            .iter()
            .filter(|b| b.kind == robots::BusKind::MitCan)
            .map(|b| {
                let motors = robot.joints_on(&b.name).count();
                (b.name.clone(), motors, w.can_bus(&b.name).unwrap().stats().frames)
            })
            .collect()
    };
    use robot_link::RobotLink;
    let cycles = |p: &MirrorPlayer| -> Vec<u64> { p.link().bus_stats().iter().map(|s| s.cycles).collect() };
    run_ticks(&mut p, &mut clock, 1..=80u32);
    assert_eq!(p.mode(), Mode::Running);
    p.step(&clock).unwrap();
    let (before, cycles_before) = (frames(&world), cycles(&p));
    p.wait_until(&mut clock, period * 81);
    run_ticks(&mut p, &mut clock, 82..=130u32);
    assert_eq!(p.mode(), Mode::Running);
    p.step(&clock).unwrap();
    let cycles_after = cycles(&p);
    let names = p.link().bus_names().to_vec();
    for ((bus, motors, a), (_, _, b)) in before.iter().zip(frames(&world)) {
        let k = names.iter().position(|n| n == bus).unwrap();
        // The CAN buses run at 250 Hz: five cycles per 20 ms tick, 250 in 50 ticks (every
        // cycle's replies are in before the tick that reads them).
        let ran = cycles_after[k] - cycles_before[k];
        assert_eq!(ran, 250, "{bus}");
        // One command and its reply per motor per cycle, nothing else.
        assert_eq!(
            b - a,
            ran * 2 * *motors as u64,
            "{bus}: {} frames in {ran} cycles",
            b - a
        );
    }
}

#[test]
fn dynamixel_servos_take_the_loops_stiffness_damping_and_torque_cap() {
    use firmware_bridge::dxl::table::addr;
    let (mut p, mut clock, world) = player(
        follower(),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        PlayOptions::default(),
    );
    let robot = p.robot().clone();
    let elbow = robot
        .config
        .joints
        .iter()
        .position(|j| j.name == "left_elbow")
        .unwrap();
    let joint = &robot.config.joints[elbow];
    let model = firmware_bridge::dxl::models::find(&joint.model).unwrap();
    let register = |a: u16| lock_servo(&world, elbow, a);
    let period = Duration::from_millis(20);
    let mut tick = |p: &mut MirrorPlayer| {
        p.step(&clock).unwrap();
        p.wait_until(&mut clock, period * p.ticks() as u32);
    };
    p.identify().unwrap();
    // Current-based position control, the torque capped at the joint's limit.
    assert_eq!(register(addr::OPERATING_MODE), 5);
    for _ in 0..10 {
        tick(&mut p);
    }
    // Mid soft start the servo holds the ramped stiffness, not the configured one.
    assert_eq!(p.mode(), Mode::SoftStart);
    let t = p.targets()[elbow];
    assert!(t.kp < joint.kp);
    let want = robots::drivers::position_gains_for(t.kp, t.kd, model);
    assert_eq!(register(addr::POSITION_P_GAIN), i64::from(want[0]));
    assert_eq!(register(addr::POSITION_D_GAIN), i64::from(want[2]));
    let cap = robots::drivers::goal_current_for(joint.torque_limit, model);
    let units = (cap / firmware_bridge::dxl::models::CURRENT_UNIT_A).round() as i64;
    assert!(units > 0);
    assert_eq!(register(addr::GOAL_CURRENT).abs(), units);
    while p.mode() != Mode::Running {
        tick(&mut p);
    }
    tick(&mut p);
    let full = robots::drivers::position_gains_for(joint.kp, joint.kd, model);
    assert_eq!(register(addr::POSITION_P_GAIN), i64::from(full[0]));
    // Damping: no stiffness, the D gain kept, torque on (not limp).
    p.request_stop();
    while p.mode() != Mode::Damped {
        tick(&mut p);
        assert!(p.ticks() < 1000);
    }
    tick(&mut p);
    assert_eq!(register(addr::POSITION_P_GAIN), 0);
    assert!(register(addr::POSITION_D_GAIN) > 0);
    assert!(world.lock().unwrap().servo_mut(elbow).unwrap().torque_enabled());
}

fn lock_servo(world: &Arc<Mutex<Mirror>>, joint: usize, address: u16) -> i64 {
    world.lock().unwrap().servo_mut(joint).unwrap().register(address)
}

#[test]
fn torque_actions_on_position_servos_are_refused_when_the_policy_loads() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let dir = std::env::temp_dir().join(format!("torque-policy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(follower())
        .unwrap()
        .replace("kind = \"position\"", "kind = \"torque\"");
    assert!(text.contains("kind = \"torque\""));
    let manifest = dir.join("torque.toml");
    std::fs::write(&manifest, text).unwrap();
    std::fs::copy(
        biped("policies/reference_follower.onnx"),
        dir.join("reference_follower.onnx"),
    )
    .unwrap();
    let err = PolicyLayout::load(&manifest, &robot).unwrap_err().to_string();
    assert!(
        err.contains("action.kind") && err.contains("left_shoulder_pitch"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_diverging_mirror_is_a_safety_stop_not_a_robot_that_keeps_moving() {
    // Masses scaled to almost nothing make the mirror's physics blow up under the motors' torques
    // (on the floor: the gantry's dampers, integrated implicitly, would calm even that).
    let mirror = MirrorConfig {
        randomization: sim2real::config::Randomization {
            mass_scale: sim2real::config::Range::fixed(1e-9),
            ..Default::default()
        },
        ..MirrorConfig::default()
    };
    let (mut p, mut clock, world) = player(
        follower(),
        biped("clips/squat.csv"),
        mirror,
        PlayOptions::default(),
    );
    let s = p.run(&mut clock).unwrap();
    let diverged = world.lock().unwrap().diverged().map(str::to_owned);
    assert!(diverged.is_some(), "the mirror did not notice: {s}");
    let stop = transition(&s, Mode::Stopping).unwrap_or_else(|| panic!("{s}"));
    assert_eq!(stop.cause, Cause::SimulationFailed, "{s}");
    assert!(matches!(
        s.outcome(),
        controller::metrics::RunOutcome::SafetyStop { .. }
    ));
    assert!(!s.success());
}

#[test]
fn a_policy_with_two_named_inputs_gets_each_its_terms() {
    let dir = std::env::temp_dir().join(format!("play-two-inputs-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The follower's graph with its observation split: "proprio" = joint_pos (20), "task" = ramp
    // (1) + ref_joint_pos (20). The model lists "task" first, so the layout must reorder.
    let script = format!(
        r#"
import onnx, numpy as np
from onnx import helper, numpy_helper, TensorProto as T
c = lambda n, v, t=np.int64: numpy_helper.from_array(np.array(v, dtype=t), n)
nodes = [
    helper.make_node("Slice", ["task", "p_lo", "p_hi"], ["psi"]),
    helper.make_node("Slice", ["task", "r_lo", "r_hi"], ["ref"]),
    helper.make_node("Sub", ["ref", "proprio"], ["gap"]),
    helper.make_node("Mul", ["psi", "gap"], ["step"]),
    helper.make_node("Add", ["proprio", "step"], ["actions"]),
]
g = helper.make_graph(nodes, "two_inputs",
    [helper.make_tensor_value_info("task", T.FLOAT, [1, 21]), helper.make_tensor_value_info("proprio", T.FLOAT, [1, 20])],
    [helper.make_tensor_value_info("actions", T.FLOAT, [1, 20])],
    [c("p_lo", [0, 0]), c("p_hi", [1, 1]), c("r_lo", [0, 1]), c("r_hi", [1, 21])])
m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)]); m.ir_version = 8
onnx.checker.check_model(m); onnx.save(m, {out:?})
"#,
        out = dir.join("two.onnx").display().to_string()
    );
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .args(["-c", &script])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let follower_text = std::fs::read_to_string(follower()).unwrap();
    let head = &follower_text[..follower_text.find("[[observation]]").unwrap()];
    let manifest = head.replace("reference_follower.onnx", "two.onnx")
        + "[[observation]]\nterm = \"joint_pos\"\nrelative = true\ninput = \"proprio\"\n\n\
           [[observation]]\nterm = \"ramp\"\ninput = \"task\"\n\n\
           [[observation]]\nterm = \"ref_joint_pos\"\nrelative = true\ninput = \"task\"\n";
    std::fs::write(dir.join("two.toml"), manifest).unwrap();
    let (mut p, mut clock, _w) = player(
        dir.join("two.toml"),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        PlayOptions::default(),
    );
    let s = p.run(&mut clock).unwrap();
    assert!(!s.fell && s.joint_rmse.to_degrees() < 3.0, "{s}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn joint_order_defaults_and_gains_can_come_from_onnx_metadata() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let dir = std::env::temp_dir().join(format!("play-meta-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The follower with metadata in the style training frameworks export, joints in reverse order.
    let names: Vec<&str> = robot
        .config
        .joints
        .iter()
        .rev()
        .map(|j| j.name.as_str())
        .collect();
    let defaults: Vec<String> = robot
        .config
        .joints
        .iter()
        .rev()
        .map(|j| j.default_position.to_string())
        .collect();
    let kp: Vec<String> = robot
        .config
        .joints
        .iter()
        .rev()
        .map(|j| (j.kp * 0.9).to_string())
        .collect();
    let script = format!(
        r#"
import onnx
m = onnx.load({src:?})
onnx.helper.set_model_props(m, dict(joint_names={names:?}, default_joint_pos={defaults:?}, joint_stiffness={kp:?}, action_scale="1.0"))
onnx.save(m, {out:?})
"#,
        src = biped("policies/reference_follower.onnx").display().to_string(),
        names = names.join(","),
        defaults = defaults.join(","),
        kp = kp.join(","),
        out = dir.join("meta.onnx").display().to_string(),
    );
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .args(["-c", &script])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(follower()).unwrap();
    let start = text.find("joints = [").unwrap();
    let end = start + text[start..].find("]\n").unwrap() + 2;
    let manifest = format!("{}{}", &text[..start], &text[end..])
        .replace("reference_follower.onnx", "meta.onnx")
        .replace("scale = 1.0\n", "");
    std::fs::write(dir.join("meta.toml"), manifest).unwrap();
    let layout = PolicyLayout::load(&dir.join("meta.toml"), &robot).unwrap();
    assert_eq!(
        layout.manifest.joints.first().map(String::as_str),
        Some("head_pitch")
    );
    assert_eq!(layout.robot_index[0], 19);
    assert!((layout.kp[3] - robot.config.joints[3].kp * 0.9).abs() < 1e-9);
    assert_eq!(layout.manifest.action.scale, Some(policy::ActionScale::One(1.0)));
    let (mut p, mut clock, _w) = player(
        dir.join("meta.toml"),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        PlayOptions::default(),
    );
    let s = p.run(&mut clock).unwrap();
    assert!(!s.fell && s.joint_rmse.to_degrees() < 3.0, "{s}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn reference_body_positions_come_from_forward_kinematics_on_the_robot_model() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let reference =
        Reference::from_clip(&Clip::load(&biped("clips/squat.csv")).unwrap(), &robot, 50.0).unwrap();
    let bodies = vec!["left_foot".to_owned(), "right_foot".to_owned(), "head".to_owned()];
    let p = controller::fk::body_positions(&robot, &reference, &bodies).unwrap();
    assert_eq!(p.len(), reference.len() * 9);
    // Standing: the ankles are under the hips (±7 cm sideways), 0.41 m below the pelvis; the head
    // joint is above it.
    let first = &p[..9];
    assert!(
        first[0].abs() < 1e-3 && (first[1] - 0.07).abs() < 1e-3 && (first[2] + 0.409).abs() < 2e-3,
        "{first:?}"
    );
    assert!((first[4] + 0.07).abs() < 1e-3);
    assert!(first[8] > 0.2);
    // Deepest squat (t = 1.5 s): the feet stay under the hips, the pelvis comes down to them.
    let deep = &p[75 * 9..75 * 9 + 9];
    assert!(deep[0].abs() < 0.01 && deep[2] > -0.35, "{deep:?}");

    // And a policy that observes them runs: the follower regenerated for a layout with the term.
    let dir = std::env::temp_dir().join(format!("play-fk-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let manifest = std::fs::read_to_string(follower()).unwrap()
        + "\n[[observation]]\nterm = \"ref_body_pos\"\nbodies = [\"left_foot\", \"right_foot\", \"head\"]\nframes = [0, 10]\n";
    std::fs::write(dir.join("reference_follower.toml"), manifest).unwrap();
    let generator = test_support::fixtures::workspace_root().join("scripts/gen_reference_policy.py");
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(generator)
        .arg(dir.join("reference_follower.toml"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let (mut pl, mut clock, _w) = player(
        dir.join("reference_follower.toml"),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        PlayOptions::default(),
    );
    let s = pl.run(&mut clock).unwrap();
    assert!(!s.fell && s.joint_rmse.to_degrees() < 3.0, "{s}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn command_values_from_the_command_line_reach_the_observation() {
    use policy::ObservationBuilder;
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let dir = std::env::temp_dir().join(format!("play-cmd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let manifest = std::fs::read_to_string(follower()).unwrap().replace(
        "reference_follower.onnx",
        biped("policies/reference_follower.onnx").to_str().unwrap(),
    ) + "\n[[observation]]\nterm = \"command\"\nvalues = [0.0, 0.0]\nscale = 2.0\n";
    std::fs::write(dir.join("cmd.toml"), manifest).unwrap();
    let mut layout = PolicyLayout::load(&dir.join("cmd.toml"), &robot).unwrap();
    assert!(
        layout
            .set_command(&[0.3])
            .unwrap_err()
            .to_string()
            .contains("2 finite values needed")
    );
    layout.set_command(&[0.3, -0.1]).unwrap();
    let slot = layout
        .slots
        .iter()
        .find(|s| s.term.name() == "command")
        .unwrap()
        .range
        .clone();
    let zeros = vec![0.0; 20];
    let still = common::Still {
        q: zeros.clone(),
        height: 0.45,
    };
    let mut b = ObservationBuilder::new(&layout);
    let mut obs = vec![0.0f32; layout.obs_len];
    let past = vec![0.0f32; 40];
    b.build(&common::at_rest(&zeros, &past, &still), &mut obs);
    assert_eq!(&obs[slot], &[0.6f32, -0.2]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn squat_and_wave_track_at_least_as_well_as_with_buses_at_the_policy_rate() {
    // Joint RMSE of the same runs when every bus was serviced once per 50 Hz tick (commit
    // fdc38d7, lockstep, same mirror): squat 1.11°, wave 1.56°.
    for (clip, before) in [("clips/squat.csv", 1.11), ("clips/wave_and_look.csv", 1.56)] {
        let (mut p, mut clock, _w) = player(
            follower(),
            biped(clip),
            MirrorConfig::default(),
            PlayOptions::default(),
        );
        let s = p.run(&mut clock).unwrap();
        let rmse = s.joint_rmse.to_degrees();
        assert!(
            !s.fell && rmse <= before,
            "{clip}: {rmse:.3}° (was {before}°)\n{s}"
        );
    }
}

#[test]
fn a_robot_collapsing_after_the_run_hands_over_has_not_fallen() {
    // Three seconds of damping after the squat, no gantry: with kp = 0 the biped folds up on the
    // floor. That is the end of a run, not a fall: falls count while the soft start, the policy or
    // the soft stop is in control.
    let options = PlayOptions {
        damping_s: 3.0,
        ..PlayOptions::default()
    };
    let (mut p, mut clock, world) = player(
        follower(),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        options,
    );
    let s = p.run(&mut clock).unwrap();
    let r = world.lock().unwrap().root_pose();
    let tilt = controller::safety::tilt_of([r[3], r[4], r[5], r[6]]);
    assert!(
        tilt > PlayOptions::default().limits.tilt,
        "the robot did not collapse: tilt {tilt:.2} rad"
    );
    assert!(!s.fell, "{s}");
    assert!(s.success(), "{s}");
}

#[test]
fn the_robots_own_position_margin_governs_its_targets() {
    // The squat comes within 0.15 rad of the left ankle's limit: a 0.16 rad margin in robot.toml
    // makes the governor hold it back; the default 0.02 rad does not.
    let text = std::fs::read_to_string(reference_robot_path()).unwrap().replacen(
        "control_rate_hz = 50.0",
        "control_rate_hz = 50.0\nposition_margin = 0.16",
        1,
    );
    let robot = Robot::from_str(&reference_robot_path(), &text).unwrap();
    let run = |robot: Robot| {
        let layout = PolicyLayout::load(&follower(), &robot).unwrap();
        let clip = Clip::load(&biped("clips/squat.csv")).unwrap();
        let reference = Reference::from_clip(&clip, &robot, layout.manifest.rate_hz).unwrap();
        let (mut p, mut clock, _w) = lockstep_player(
            robot,
            layout,
            reference,
            PlayOptions::default(),
            MirrorConfig::default(),
            Arc::new(AtomicBool::new(false)),
        )
        .unwrap();
        p.run(&mut clock).unwrap()
    };
    let margin = run(robot);
    let default = run(Robot::load(&reference_robot_path()).unwrap());
    assert_eq!(default.limited_ticks, 0, "{default}");
    assert!(margin.limited_ticks > 0, "{margin}");
}

#[test]
fn end_stand_keeps_the_robot_standing_under_the_policy_until_the_operator_stops() {
    let options = PlayOptions {
        end: controller::player::EndMode::Stand,
        ..PlayOptions::default()
    };
    let (mut p, mut clock, world) = player(
        follower(),
        biped("clips/squat.csv"),
        MirrorConfig::default(),
        options,
    );
    p.identify().unwrap();
    let period = Duration::from_millis(20);
    // Soft start, ramp, the 7 s squat, the blend: then 3 s more of standing.
    let clip_ticks = p.reference_ticks() as u32;
    let until = clip_ticks + 200 + 150;
    run_ticks(&mut p, &mut clock, 1..=until);
    assert_eq!(p.mode(), Mode::Running, "{:?}", p.transitions());
    let robot = p.robot().clone();
    for (t, j) in p.targets().iter().zip(&robot.config.joints) {
        assert!(
            (t.q - j.default_position).abs() < 1e-6 && t.kp > 0.0,
            "{}: {:?}",
            j.name,
            t
        );
    }
    let r = world.lock().unwrap().root_pose();
    assert!(
        controller::safety::tilt_of([r[3], r[4], r[5], r[6]]) < 0.1,
        "standing"
    );
    // The operator stops it: a soft stop, then damping, then off.
    p.request_stop();
    let mut k = until;
    while p.mode() != Mode::Off {
        k += 1;
        p.step(&clock).unwrap();
        p.wait_until(&mut clock, period * k);
        assert!(k < until + 200, "{:?}", p.transitions());
    }
    let stop = p.transitions().iter().find(|t| t.to == Mode::Stopping).unwrap();
    assert_eq!((stop.from, stop.cause), (Mode::Running, Cause::StopRequested));
}

#[test]
fn a_run_whose_every_command_the_governor_limited_does_not_end_as_a_success() {
    // The follower with its actions scaled ×10: every target lands beyond the joints' limits.
    // On the gantry the robot cannot fall, so only the governor's count can tell.
    let dir = std::env::temp_dir().join(format!("robodeploy-saturated-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let policies = reference_robot_path().with_file_name("policies");
    let text = std::fs::read_to_string(policies.join("reference_follower.toml"))
        .unwrap()
        .replacen("scale = 1.0\n", "scale = 10.0\n", 1)
        .replace(
            "onnx = \"reference_follower.onnx\"",
            &format!("onnx = {:?}", policies.join("reference_follower.onnx")),
        );
    assert!(text.contains("scale = 10.0"));
    let manifest = dir.join("scaled.toml");
    std::fs::write(&manifest, text).unwrap();
    let (code, out, err) = test_support::bin::run_within(
        &[
            "play",
            "--policy",
            manifest.to_str().unwrap(),
            "--gantry",
            "--max-seconds",
            "4",
            "--no-record",
        ],
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(1), "{out}{err}");
    assert!(
        out.contains(
            "success (as tracking trainers end an episode: no fall, no safety stop, played to the end"
        ),
        "{out}"
    );
    assert!(out.contains("): NO"), "{out}");
    let last = out.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("result: finished, but the governor limited")
            && last.contains("of the policy's commands"),
        "{out}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `robodeploy play ARGS`: exit code and stdout+stderr.
fn play_cli(args: &[&str]) -> (Option<i32>, String) {
    let (code, out, err) =
        test_support::bin::run_within(&[&["play"], args].concat(), Duration::from_secs(300));
    (code, format!("{out}{err}"))
}

/// A figure of a summary line: the number after `key`.
fn figure(out: &str, key: &str) -> f64 {
    let line = out
        .lines()
        .find(|l| l.starts_with(key))
        .unwrap_or_else(|| panic!("{key} in:\n{out}"));
    line[key.len()..]
        .trim_start()
        .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-'))
        .next()
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("{line}"))
}

#[test]
fn the_direct_mirror_plays_a_clip_as_the_wires_do_and_says_which_ran() {
    let robot = biped("robot.toml");
    let clip = biped("clips/squat.csv");
    let common = [
        "--robot",
        robot.to_str().unwrap(),
        "--clip",
        clip.to_str().unwrap(),
        "--no-record",
    ];
    let (code, wires) = play_cli(&common);
    assert_eq!(code, Some(0), "{wires}");
    let (code, direct) = play_cli(&[&common[..], &["--fidelity", "direct"]].concat());
    assert_eq!(code, Some(0), "{direct}");
    assert!(
        direct.contains("in lockstep, direct: the trainer's actuator law on MuJoCo, no buses"),
        "{direct}"
    );
    assert!(!wires.contains("direct:"), "{wires}");
    // The same law on the same physics: what the wires add (a bus cycle's delay, the ramp
    // between ticks, the devices' resolution) moves the tracking by a fraction of a degree.
    // Measured: 0.98° / 0.7 cm on the wires, 1.04° / 0.8 cm direct.
    for (key, tolerance) in [("joint tracking RMSE:", 0.3), ("root position RMSE:", 0.5)] {
        let (w, d) = (figure(&wires, key), figure(&direct, key));
        assert!((w - d).abs() <= tolerance, "{key} wires {w}, direct {d}");
    }
    for out in [&wires, &direct] {
        assert!(
            out.lines().any(
                |l| l.starts_with("success (as tracking trainers end an episode") && l.ends_with(": yes")
            ),
            "{out}"
        );
    }
    // The mirror file says it too; a direct mirror has no wires to serve in real time.
    let dir = std::env::temp_dir().join(format!("play-direct-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mirror = dir.join("mirror.toml");
    std::fs::write(&mirror, "fidelity = \"direct\"\n").unwrap();
    let (code, out) = play_cli(
        &[
            &common[..],
            &["--mirror", mirror.to_str().unwrap(), "--max-seconds", "1"],
        ]
        .concat(),
    );
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("direct: the trainer's actuator law"), "{out}");
    let (code, out) = play_cli(&[&common[..], &["--mirror", mirror.to_str().unwrap(), "--wall"]].concat());
    assert_eq!(code, Some(2), "{out}");
    assert!(out.contains("--wall") && out.contains("direct fidelity"), "{out}");
    // Faults act on devices and wires: a direct mirror has none, and says so.
    std::fs::write(
        &mirror,
        "fidelity = \"direct\"\n[[faults]]\nat_s = 1.0\njoint = \"left_knee\"\nfault = { kind = \"vanish\" }\n",
    )
    .unwrap();
    let (code, out) = play_cli(&[&common[..], &["--mirror", mirror.to_str().unwrap()]].concat());
    assert_ne!(code, Some(0), "{out}");
    assert!(out.contains("faults act on devices and wires"), "{out}");
    // batch takes the same choice and names it above its table.
    let (code, out, err) = test_support::bin::run_within(
        &[
            "batch",
            "--robot",
            robot.to_str().unwrap(),
            "--clips",
            clip.to_str().unwrap(),
            "--seeds",
            "0-0",
            "--fidelity",
            "direct",
        ],
        Duration::from_secs(300),
    );
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(
        out.contains("mirror: direct (the trainer's actuator law on MuJoCo, no buses)"),
        "{out}"
    );
    let d = figure(&direct, "joint tracking RMSE:");
    let row = out
        .lines()
        .find(|l| l.starts_with("squat.csv"))
        .unwrap_or_else(|| panic!("{out}"));
    assert!(
        row.contains(&format!("{d:.2}")),
        "the batch's run is play's: {row} vs {d}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn physically_impossible_feedback_is_a_device_fault_on_the_tick_it_arrives() {
    let cases: [(&str, garbled_link::Garble, &str); 6] = [
        ("a joint at 100 rad", |s| s.q[3] = 100.0, "implausible position"),
        ("a joint at 1e30 rad", |s| s.q[0] = 1e30, "implausible position"),
        ("a joint at 1e4 rad/s", |s| s.qd[5] = -1e4, "implausible speed"),
        ("a torque of 1e6 N·m", |s| s.tau[2] = 1e6, "implausible torque"),
        (
            "a gyro at 1e30 rad/s",
            |s| s.gyro[1] = 1e30,
            "IMU: implausible turn rate",
        ),
        (
            "a quaternion of norm 2",
            |s| s.quat = s.quat.map(|v| 2.0 * v),
            "IMU: implausible orientation",
        ),
    ];
    for (what, garble, said) in cases {
        let robot = Robot::load(&reference_robot_path()).unwrap();
        let layout = PolicyLayout::load(&follower(), &robot).unwrap();
        let clip = Clip::load(&biped("clips/squat.csv")).unwrap();
        let reference = Reference::from_clip(&clip, &robot, layout.manifest.rate_hz).unwrap();
        let world = Arc::new(Mutex::new(
            Mirror::new(robot.clone(), MirrorConfig::default()).unwrap(),
        ));
        let io = garbled_link::Garbled {
            inner: sim2real::link::lockstep_robot(&robot, &world).unwrap(),
            reads: 0,
            from: 150,
            garble,
        };
        let mut clock = LockstepClock::new(Arc::clone(&world));
        let mut p = Player::new(
            robot,
            layout,
            reference,
            PlayOptions::default(),
            io,
            Arc::new(AtomicBool::new(false)),
        )
        .unwrap();
        let s = p.run(&mut clock).unwrap();
        let t = p.transitions();
        let stop = t
            .iter()
            .find(|t| matches!(t.to, Mode::Damped | Mode::Stopping))
            .unwrap_or_else(|| panic!("{what}: no stop\n{s}"));
        // A device fault damps at once, on the tick whose read carried it (identify's read
        // counts as the first).
        assert!(
            matches!(stop.cause, Cause::ImplausibleFeedback { .. }) && stop.to == Mode::Damped,
            "{what}: {:?}\n{s}",
            stop
        );
        assert!(
            (147..=149).contains(&stop.tick),
            "{what}: tick {}\n{s}",
            stop.tick
        );
        let text = stop.cause.to_string();
        assert!(
            text.contains(said) && text.contains("device fault"),
            "{what}: {text}"
        );
    }
}
