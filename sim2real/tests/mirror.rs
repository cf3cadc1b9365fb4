//! The mirrored reference biped, driven through its buses by the real host drivers in lockstep.

use std::time::Duration;

use robots::{Robot, reference_robot_path};
use sim2real::config::{FaultKind, MirrorConfig, Randomization, Range, ScheduledFault};
use sim2real::host::MirrorHost;
use sim2real::mirror::Mirror;

const TICK: Duration = Duration::from_millis(20);

struct Host {
    inner: MirrorHost,
    robot: Robot,
    default_pose: Vec<f64>,
}

fn host(config: MirrorConfig) -> Host {
    host_of(Robot::load(&reference_robot_path()).unwrap(), config)
}

fn host_of(robot: Robot, config: MirrorConfig) -> Host {
    let default_pose = robot.config.joints.iter().map(|j| j.default_position).collect();
    Host {
        inner: MirrorHost::start(robot.clone(), config).unwrap(),
        robot,
        default_pose,
    }
}

fn on_gantry() -> MirrorConfig {
    MirrorConfig {
        gantry: true,
        ..MirrorConfig::default()
    }
}

impl Host {
    /// Holds the default pose for `seconds`; returns a log of what the buses and the IMU reported.
    fn run(&mut self, seconds: f64) -> Vec<u64> {
        let mut log = Vec::new();
        let ticks = (seconds / TICK.as_secs_f64()).round() as u32;
        let start = self.inner.now();
        for k in 1..=ticks {
            self.inner
                .command_positions(&self.robot, &self.default_pose)
                .unwrap();
            let s = self.inner.state();
            log.extend(s.q.iter().map(|q| q.to_bits()));
            if s.imu_missed == 0 {
                log.extend(s.gyro.map(f64::to_bits));
                log.extend(s.quat.map(f64::to_bits));
            }
            self.inner.wait_until(start + TICK * k);
        }
        log
    }
}

#[test]
fn the_biped_stands_ten_seconds_under_its_own_firmware_pd() {
    let mut h = host(MirrorConfig::default());
    let start = h.inner.world.lock().unwrap().root_pose();
    h.run(10.0);
    let w = h.inner.world.lock().unwrap();
    let end = w.root_pose();
    assert!(
        end[2] > 0.9 * start[2],
        "pelvis fell from {:.3} m to {:.3} m",
        start[2],
        end[2]
    );
    // Upright: the pelvis z axis still points up.
    let [_, _, _, qw, qx, qy, _] = end;
    let up_z = 1.0 - 2.0 * (qx * qx + qy * qy);
    assert!(up_z > 0.97, "tilted: z·z = {up_z:.3}, w = {qw:.3}");
    for (q, j) in w.joint_positions().zip(&h.robot.config.joints) {
        assert!(
            (q - j.default_position).abs() < 0.15,
            "{}: {q:.3} vs default {:.3}",
            j.name,
            j.default_position
        );
    }
    assert!(w.stats().physics_steps >= 10_000 && w.stats().imu_outputs >= 1_990);
    // The IMU says the same: gravity along its z.
    drop(w);
    let accel = h.inner.state().accel;
    assert!((accel[2] - 9.81).abs() < 1.0, "{accel:?}");
}

#[test]
fn on_the_gantry_the_feet_stay_off_the_floor_and_the_pose_holds() {
    let mut h = host(MirrorConfig {
        gantry: true,
        ..MirrorConfig::default()
    });
    let start = h.inner.world.lock().unwrap().root_pose();
    h.run(3.0);
    let w = h.inner.world.lock().unwrap();
    let end = w.root_pose();
    assert!(
        (end[2] - start[2]).abs() < 0.01 && (end[0] - start[0]).abs() < 0.01,
        "{start:?} → {end:?}"
    );
    assert_eq!(w.data().ffi().ncon, 0, "nothing touches the floor");
    for (q, j) in w.joint_positions().zip(&h.robot.config.joints) {
        assert!((q - j.default_position).abs() < 0.1, "{}: {q:.3}", j.name);
    }
}

#[test]
fn the_same_seed_gives_the_same_log_and_another_seed_does_not() {
    let config = |seed| MirrorConfig {
        seed,
        randomization: Randomization {
            mass_scale: Range(0.9, 1.1),
            friction_scale: Range(0.8, 1.2),
            strength_scale: Range(0.9, 1.0),
            usb_latency_us: Range(0.0, 500.0),
            imu_noise_scale: 1.0,
            imu_gyro_bias_walk_dps: 0.01,
            imu_accel_bias_walk: 0.005,
        },
        ..MirrorConfig::default()
    };
    let a = host(config(7)).run(1.0);
    let b = host(config(7)).run(1.0);
    let c = host(config(8)).run(1.0);
    assert!(!a.is_empty());
    assert!(a == b, "same seed, different logs");
    assert!(a != c, "different seeds, same log");
}

#[test]
fn scheduled_faults_reach_the_devices_at_their_time() {
    let mut h = host(MirrorConfig {
        faults: vec![
            ScheduledFault {
                at_s: 0.5,
                joint: "left_elbow".into(),
                fault: FaultKind::Vanish,
            },
            ScheduledFault {
                at_s: 0.5,
                joint: "right_knee".into(),
                fault: FaultKind::Silent { count: None },
            },
        ],
        gantry: true,
        ..MirrorConfig::default()
    });
    h.run(0.4);
    assert!(h.inner.state().missed.iter().all(|&m| m == 0));
    h.run(0.2);
    let index = |name: &str| h.robot.config.joints.iter().position(|j| j.name == name).unwrap();
    let missed = &h.inner.state().missed;
    assert!(missed[index("left_elbow")] > 0 && missed[index("right_knee")] > 0);
    let stale = missed.iter().filter(|&&m| m > 0).count();
    assert_eq!(stale, 2, "only the two faulted joints: {missed:?}");
    assert_eq!(h.inner.world.lock().unwrap().stats().faults_applied, 2);
}

#[test]
fn a_model_without_imu_sensors_gets_them_added_and_reads_the_same() {
    // The reference model with its three IMU sensors removed: the mirror adds a gyro, an
    // accelerometer and a frame orientation at the IMU site through MuJoCo's model-editing API,
    // and the run is the same, bit for bit, as with the model's own sensors.
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let dir = std::env::temp_dir().join(format!("mirror-nosensor-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let xml = std::fs::read_to_string(&robot.mjcf_path).unwrap();
    let stripped: String = xml
        .lines()
        .filter(|l| !l.contains("name=\"imu_"))
        .map(|l| format!("{l}\n"))
        .collect();
    assert_eq!(xml.lines().count() - stripped.lines().count(), 3);
    std::fs::write(dir.join("biped.xml"), stripped).unwrap();
    let text = std::fs::read_to_string(reference_robot_path()).unwrap();
    let bare = Robot::from_str(&dir.join("robot.toml"), &text).unwrap();
    assert_eq!(bare.imu_sensors(), [None, None, None]);
    let mut added = host_of(bare, MirrorConfig::default());
    let mut own = host(MirrorConfig::default());
    assert_eq!(added.run(1.0), own.run(1.0));
    // Standing still: the accelerometer feels gravity, up.
    let accel = added.inner.state().accel;
    assert!((accel[2] - 9.81).abs() < 0.3, "{accel:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_rendered_frame_shows_the_robot_against_floor_and_sky() {
    use sim2real::render::{CameraSpec, SKY};
    let h = host(MirrorConfig::default());
    let camera = CameraSpec {
        width: 96,
        height: 72,
        ..CameraSpec::default()
    };
    let image = h.inner.world.lock().unwrap().render(&camera);
    assert_eq!(image.rgb.len(), 96 * 72 * 3);
    // Sky at the top, floor at the bottom, robot in the middle.
    let px = |x: usize, y: usize| &image.rgb[(y * 96 + x) * 3..(y * 96 + x) * 3 + 3];
    assert_eq!(px(2, 1), SKY);
    assert_ne!(px(48, 70), SKY);
    let middle: Vec<_> = (30..66).map(|x| px(x, 36).to_vec()).collect();
    assert!(
        middle.iter().any(|p| p != &SKY.to_vec()),
        "nothing in the middle of the frame"
    );
    let coverage = image.coverage(SKY);
    assert!(coverage > 0.2 && coverage < 0.95, "coverage {coverage}");
    let path = std::env::temp_dir().join(format!("mirror-frame-{}.png", std::process::id()));
    image.save_png(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    std::fs::remove_file(&path).unwrap();
}

/// The reference robot, its MJCF given a `<position>` actuator per joint (in joint order) with
/// robot.toml's gains, written into `dir`.
fn position_actuated_robot(dir: &std::path::Path) -> Robot {
    let base = Robot::load(&reference_robot_path()).unwrap();
    std::fs::create_dir_all(dir).unwrap();
    let servos: String = base
        .config
        .joints
        .iter()
        .map(|j| {
            format!(
                "    <position joint=\"{}\" kp=\"{}\" kv=\"{}\"/>\n",
                j.mjcf_joint, j.kp, j.kd
            )
        })
        .collect();
    let xml = std::fs::read_to_string(&base.mjcf_path).unwrap().replace(
        "  <sensor>",
        &format!("  <actuator>\n{servos}  </actuator>\n  <sensor>"),
    );
    std::fs::write(dir.join("biped.xml"), xml).unwrap();
    let text = std::fs::read_to_string(reference_robot_path()).unwrap();
    Robot::from_str(&dir.join("robot.toml"), &text).unwrap()
}

#[test]
fn models_with_their_own_position_actuators_track_the_firmware_goals() {
    let dir = std::env::temp_dir().join(format!("mirror-position-{}", std::process::id()));
    let mut h = host_of(position_actuated_robot(&dir), on_gantry());
    assert_eq!(h.inner.world.lock().unwrap().position_actuated_joints(), 20);
    h.run(2.0);
    let w = h.inner.world.lock().unwrap();
    let ctrl = w.data().ctrl();
    for (k, (q, j)) in w.joint_positions().zip(&h.robot.config.joints).enumerate() {
        // The model's servo got the firmware's goal (the default pose, through the bus).
        assert!(
            (ctrl[k] - j.default_position).abs() < 2e-3,
            "{}: ctrl {}",
            j.name,
            ctrl[k]
        );
        assert!((q - j.default_position).abs() < 0.1, "{}: {q:.3}", j.name);
    }
    assert!(w.data().qfrc_applied().iter().all(|&f| f == 0.0));
    drop(w);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_position_actuator_gives_no_more_torque_than_the_servo_it_stands_for() {
    // The model's own servo for head_pitch has kp 4 N·m/rad: 0.6 rad against the jig asks it for
    // 2.4 N·m, where the XL430 under its PWM Limit gives 1.2 N·m (the joint's limit).
    let dir = std::env::temp_dir().join(format!("mirror-position-cap-{}", std::process::id()));
    let mut h = host_of(position_actuated_robot(&dir), on_gantry());
    let robot = h.robot.clone();
    let j = robot
        .config
        .joints
        .iter()
        .position(|x| x.name == "head_pitch")
        .unwrap();
    h.inner
        .world
        .lock()
        .unwrap()
        .set_jig(Some(h.default_pose.clone()));
    let mut pose = h.default_pose.clone();
    pose[j] += 0.6;
    let start = h.inner.now();
    let mut worst = 0.0f64;
    for k in 1..=100u32 {
        h.inner.command_positions(&robot, &pose).unwrap();
        h.inner.wait_until(start + TICK * k);
        let force = h.inner.world.lock().unwrap().data().actuator_force()[j];
        worst = worst.max(force.abs());
    }
    assert!(
        worst <= 1.2 + 1e-6 && worst > 1.1,
        "actuator force {worst:.3} N·m"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn counted_faults_end_after_their_count_on_can_motors_and_the_imu() {
    let fault = |joint: &str, fault| ScheduledFault {
        at_s: 0.2,
        joint: joint.into(),
        fault,
    };
    let mut h = host(MirrorConfig {
        faults: vec![
            fault("right_knee", FaultKind::Silent { count: Some(3) }),
            fault("left_knee", FaultKind::CorruptCrc { count: 2 }),
            fault("imu", FaultKind::Silent { count: Some(10) }),
        ],
        gantry: true,
        ..MirrorConfig::default()
    });
    let index = |name: &str| h.robot.config.joints.iter().position(|j| j.name == name).unwrap();
    let (right, left) = (index("right_knee"), index("left_knee"));
    let mut worst = (0, 0, 0);
    // Read twice per CAN cycle (250 Hz): every cycle's count is seen.
    let start = h.inner.now();
    let cycle = Duration::from_millis(2);
    for k in 1..=250u32 {
        h.inner.command_positions(&h.robot, &h.default_pose).unwrap();
        h.inner.wait_until(start + cycle * k);
        let s = h.inner.state();
        worst = (
            worst.0.max(s.missed[right]),
            worst.1.max(s.missed[left]),
            worst.2.max(s.imu_missed),
        );
    }
    // One command per bus cycle: 3 (and 2) lost replies are 3 (and 2) stale cycles in a row,
    // then back.
    assert_eq!(worst.0, 3);
    assert_eq!(worst.1, 2);
    // The IMU lost exactly its 10 output cycles (a tick went without a sample), then came back.
    assert!(worst.2 >= 1, "{worst:?}");
    h.run(0.1);
    let s = h.inner.state();
    assert_eq!((s.missed[right], s.missed[left], s.imu_missed), (0, 0, 0));
    let mut clean = host(MirrorConfig {
        gantry: true,
        ..MirrorConfig::default()
    });
    // As long as the faulty run: 0.5 s at the bus rate, 0.1 s at the tick rate.
    for _ in 0..30 {
        clean.run(0.02);
    }
    let outputs = |h: &Host| h.inner.world.lock().unwrap().stats().imu_outputs;
    assert_eq!(outputs(&clean) - outputs(&h), 10);
}

#[test]
fn a_fault_plan_that_means_nothing_is_refused_by_name() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let refuse = |joint: &str, fault| {
        let config = MirrorConfig {
            faults: vec![ScheduledFault {
                at_s: 1.0,
                joint: joint.into(),
                fault,
            }],
            ..MirrorConfig::default()
        };
        Mirror::new(robot.clone(), config).unwrap_err().to_string()
    };
    let e = refuse("right_knee", FaultKind::Silent { count: Some(0) });
    assert!(e.contains("right_knee") && e.contains("count = 0"), "{e}");
    let e = refuse("left_elbow", FaultKind::CorruptCrc { count: 0 });
    assert!(e.contains("count = 0"), "{e}");
    let e = refuse("imu", FaultKind::Overheat);
    assert!(e.contains("imu") && e.contains("overheat"), "{e}");
    let e = refuse("tail", FaultKind::Vanish);
    assert!(e.contains("unknown joint \"tail\""), "{e}");
}

#[test]
fn a_scheduled_push_shoves_the_root_while_it_lasts_and_only_then() {
    use sim2real::config::Push;
    let shove = |force_n| {
        let mut h = host(MirrorConfig {
            gantry: true,
            pushes: vec![Push {
                at_s: 0.5,
                duration_s: 0.3,
                force_n,
            }],
            ..MirrorConfig::default()
        });
        let start = h.inner.world.lock().unwrap().root_pose();
        h.run(0.4);
        let before = h.inner.world.lock().unwrap().root_pose();
        h.run(0.3);
        let during = h.inner.world.lock().unwrap().root_pose();
        h.run(1.5);
        let after = h.inner.world.lock().unwrap().root_pose();
        (start[0], before[0], during[0], after[0])
    };
    // The gantry's spring (2·10⁴ N/m) gives 200 N a 1 cm deflection.
    let (start, before, during, after) = shove([200.0, 0.0, 0.0]);
    assert!(
        (before - start).abs() < 1e-3,
        "moved before the push: {start} → {before}"
    );
    assert!(during - start > 0.005, "not shoved forward: {start} → {during}");
    assert!(
        (after - start).abs() < 2e-3,
        "not back after the push: {start} → {after}"
    );
    let (start, _, during, _) = shove([-200.0, 0.0, 0.0]);
    assert!(start - during > 0.005, "not shoved backward: {start} → {during}");
    // Out of range: refused by field.
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let config = MirrorConfig {
        pushes: vec![Push {
            at_s: 1.0,
            duration_s: 0.1,
            force_n: [0.0, f64::NAN, 0.0],
        }],
        ..MirrorConfig::default()
    };
    let (field, _) = config.check(&robot).unwrap_err();
    assert_eq!(field, "pushes[0].force_n");
}

#[test]
fn motors_drop_torque_after_the_command_timeout_robot_toml_gives_their_bus() {
    // can0 with an 8 ms timeout (two 250 Hz cycles); can1 keeps its default (10 cycles, 40 ms).
    let text = std::fs::read_to_string(reference_robot_path()).unwrap().replacen(
        "name = \"can0\"",
        "name = \"can0\"\ncommand_timeout_ms = 8.0",
        1,
    );
    let robot = Robot::from_str(&reference_robot_path(), &text).unwrap();
    let mut h = host_of(robot, on_gantry());
    h.run(0.2);
    let index = |name: &str| h.robot.config.joints.iter().position(|j| j.name == name).unwrap();
    let (left, right) = (index("left_knee"), index("right_knee"));
    let enabled = |h: &mut Host, j: usize| h.inner.world.lock().unwrap().motor_mut(j).unwrap().enabled();
    assert!(enabled(&mut h, left) && enabled(&mut h, right));
    // The host goes quiet for 20 ms (the world runs on without its buses being served).
    {
        use firmware_bridge::time::SimWorld;
        let mut w = h.inner.world.lock().unwrap();
        let until = w.now() + Duration::from_millis(20);
        while w.now() < until {
            w.step_until(until);
        }
    }
    assert!(
        !enabled(&mut h, left),
        "can0's motors keep torque past their 8 ms timeout"
    );
    assert!(enabled(&mut h, right), "can1's 40 ms timeout has not passed");
}

#[test]
fn a_linear_bus_ramps_its_targets_over_the_policy_period_and_a_hold_bus_jumps() {
    let text = std::fs::read_to_string(reference_robot_path()).unwrap().replacen(
        "name = \"can0\"",
        "name = \"can0\"\ninterpolation = \"linear\"",
        1,
    );
    let robot = Robot::from_str(&reference_robot_path(), &text).unwrap();
    let mut host = MirrorHost::start(
        robot.clone(),
        MirrorConfig {
            gantry: true,
            ..MirrorConfig::default()
        },
    )
    .unwrap();
    let mut pose: Vec<f64> = robot.config.joints.iter().map(|j| j.default_position).collect();
    let index = |name: &str| robot.config.joints.iter().position(|j| j.name == name).unwrap();
    let (left, right) = (index("left_knee"), index("right_knee"));
    let start = host.now();
    let tick = Duration::from_millis(20);
    for k in 1..=15u32 {
        host.command_positions(&robot, &pose).unwrap();
        host.wait_until(start + tick * k);
    }
    let command = |host: &MirrorHost, j: usize| {
        host.world
            .lock()
            .unwrap()
            .motor_mut(j)
            .map(|m| m.command())
            .unwrap()
    };
    let (from_left, from_right) = (command(&host, left).p, command(&host, right).p);
    // A new target 0.1 rad away on both knees, then five 250 Hz cycles to the next tick.
    pose[left] += 0.1;
    pose[right] += 0.1;
    host.command_positions(&robot, &pose).unwrap();
    let cycle = Duration::from_millis(4);
    let after = start + tick * 15;
    for k in 1..=5u32 {
        host.wait_until(after + cycle * k);
        let (l, r) = (command(&host, left), command(&host, right));
        // can0 ramps: a fifth of the step per cycle, reaching the target in the last cycle
        // before the next tick; the stiffness stays (it did not change).
        assert!(
            (l.p - from_left - 0.1 * f64::from(k) / 5.0).abs() < 1e-3,
            "cycle {k}: {}",
            l.p - from_left
        );
        assert!(l.kp > 0.0);
        // can1 holds: the whole step from the first cycle.
        assert!(
            (r.p - from_right - 0.1).abs() < 1e-3,
            "cycle {k}: {}",
            r.p - from_right
        );
    }
}

#[test]
fn the_imu_line_is_polled_at_its_own_rate_between_ticks() {
    let mut h = host(MirrorConfig::default());
    let robot = h.robot.clone();
    let poll = robot.bus_timing(&robot.config.imu.bus).unwrap().period;
    assert_eq!(poll, Duration::from_millis(1));
    let output = Duration::try_from_secs_f64(1.0 / robot.config.imu.rate_hz).unwrap();
    let mut ages = std::collections::BTreeSet::new();
    for _ in 0..50 {
        h.run(0.02);
        let age = h.inner.state().imu_age;
        // The newest 200 Hz sample, seen by the 1 kHz poll after it arrived: younger than one
        // output period, stamped on the poll's grid.
        assert!(age < output, "{age:?}");
        assert_eq!(age.as_nanos() % poll.as_nanos(), 0, "{age:?}");
        ages.insert(age);
    }
    // Polled only at the ticks, every sample would be 0 ms old when read.
    assert!(ages.len() > 1, "{ages:?}");
}

#[test]
fn feedback_is_exactly_one_bus_period_old_at_each_tick_in_lockstep() {
    let mut h = host(MirrorConfig::default());
    h.run(0.5);
    let robot = h.robot.clone();
    for (i, j) in robot.config.joints.iter().enumerate() {
        let period = robot.bus_timing(&j.bus).unwrap().period;
        // Sampled at the start of the bus's last complete cycle, which started one period
        // before the tick (cycles fall on the ticks' instants).
        assert_eq!(h.inner.state().age[i], period, "{}", j.name);
    }
}

/// Holds every joint in the jig (an obstacle that does not give), asks `joint` to go `push` rad
/// further for 300 bus cycles, and asserts that the torque its actuator applied and the torque its
/// bus reported reach the joint's limit but never exceed it by more than `slack`. Returns the limit.
fn push_against_the_jig(joint: &str, push: f64, slack: f64) -> f64 {
    push_against_the_jig_of(Robot::load(&reference_robot_path()).unwrap(), joint, push, slack)
}

fn push_against_the_jig_of(robot: Robot, joint: &str, push: f64, slack: f64) -> f64 {
    let mut h = host_of(robot, on_gantry());
    let robot = h.robot.clone();
    let j = robot.config.joints.iter().position(|x| x.name == joint).unwrap();
    let limit = robot.config.joints[j].torque_limit;
    h.inner
        .world
        .lock()
        .unwrap()
        .set_jig(Some(h.default_pose.clone()));
    let mut pose = h.default_pose.clone();
    pose[j] += push;
    let start = h.inner.now();
    let cycle = robot.bus_timing(&robot.config.joints[j].bus).unwrap().period;
    let (mut applied, mut reported) = (0.0f64, 0.0f64);
    for k in 1..=300u32 {
        h.inner.command_positions(&robot, &pose).unwrap();
        h.inner.wait_until(start + cycle * k);
        let mut w = h.inner.world.lock().unwrap();
        let torque = match w.motor_mut(j) {
            Some(m) => m.torque(),
            None => w.servo_mut(j).unwrap().applied_torque(),
        };
        applied = applied.max(torque.abs());
        reported = reported.max(h.inner.state().tau[j].abs());
        assert!(
            applied <= limit + slack && reported <= limit + slack,
            "{joint}: applied {applied:.2}, measured {reported:.2} N·m, limit {limit}"
        );
    }
    // Pushed to the limit, and the bus sees it.
    assert!(
        applied > 0.9 * limit && reported > 0.9 * limit,
        "{joint}: applied {applied:.2}, measured {reported:.2} N·m"
    );
    limit
}

#[test]
fn a_joint_pushed_against_an_obstacle_never_exceeds_its_torque_limit() {
    // The left knee asked 0.5 rad further: 150 N·m/rad × 0.5 rad = 75 N·m, within its AK10-9's
    // 65 N·m, beyond the joint's 40 N·m torque limit in robot.toml. The bound at each bus cycle
    // holds it (0.5 N·m for the reply's torque resolution and the firmware's own step).
    assert_eq!(push_against_the_jig("left_knee", 0.5, 0.5), 40.0);
}

#[test]
fn a_dynamixel_joint_pushed_against_an_obstacle_never_exceeds_its_torque_limit() {
    // head_pitch on an XL430-W250 (stall 1.5 N·m, no current sensing), limit 1.2 N·m: asked
    // 0.6 rad further at 4 N·m/rad = 2.4 N·m, the servo would give its whole stall torque; the
    // PWM Limit the driver programs caps it (0.02 N·m: Present Load's 0.1 % steps).
    assert_eq!(push_against_the_jig("head_pitch", 0.6, 0.02), 1.2);
}

#[test]
fn a_motor_model_of_the_robots_own_drives_driver_and_firmware_alike() {
    // The left knee on "RD-X20", a model robot.toml defines: ±20 rad where the AK10-9 maps
    // ±12.5. Driver and emulated firmware both take the robot's table: a knee held at its
    // default shows it (with either on the shipped table the angle would scale by 12.5/20).
    let text = std::fs::read_to_string(reference_robot_path())
        .unwrap()
        .replacen("id = 4\nmodel = \"AK10-9\"", "id = 4\nmodel = \"RD-X20\"", 1)
        .replacen(
            "\n[[buses]]",
            "\n[[mit_models]]\nname = \"RD-X20\"\nreply = \"cubemars\"\nposition = [-20.0, 20.0]\n\
             velocity = [-40.0, 40.0]\ntorque = [-60.0, 60.0]\nkp = [0.0, 500.0]\nkd = [0.0, 5.0]\n\
             rated_torque = 20.0\n\n[[buses]]",
            1,
        );
    let robot = Robot::from_str(&reference_robot_path(), &text).unwrap();
    let knee = robot
        .config
        .joints
        .iter()
        .position(|j| j.name == "left_knee")
        .unwrap();
    assert_eq!(robot.config.joints[knee].model, "RD-X20");
    let mut h = host_of(robot, on_gantry());
    h.run(2.0);
    let mut w = h.inner.world.lock().unwrap();
    assert_eq!(w.motor_mut(knee).unwrap().config().model.p_max, 20.0);
    let q = w.joint_positions().nth(knee).unwrap();
    assert!((q - 0.5).abs() < 0.02, "knee at {q:.3} rad, default 0.5");
}

#[test]
fn a_servo_variant_of_the_robots_own_is_driven_and_emulated_with_its_constants() {
    // head_pitch on a 7.4 V winding of the XL430-W250 (stall 0.9 N·m there), limited to 0.8 N·m:
    // the driver's PWM Limit comes from the variant's stall torque and the emulated servo runs on
    // the variant's constants and supply; with either side on the shipped 12 V constants the
    // joint would stall at 0.48 N·m instead of reaching its limit.
    let text = std::fs::read_to_string(reference_robot_path())
        .unwrap()
        .replacen(
            "id = 8\nmodel = \"XL430-W250\"",
            "id = 8\nmodel = \"XL430-W250-7V4\"",
            1,
        )
        .replacen(
            "\n[[buses]]",
            "\n[[servo_models]]\nname = \"XL430-W250-7V4\"\nbase = \"XL430-W250\"\nnominal_voltage = 7.4\n\
             stall_torque = 0.9\nstall_current = 0.85\nno_load_speed = 38.0\n\n[[buses]]",
            1,
        );
    let text = {
        // The head's limits fit the slower, weaker variant.
        let at = text.find("name = \"head_pitch\"").unwrap();
        let (head, tail) = text.split_at(at);
        format!(
            "{head}{}",
            tail.replacen("velocity_limit = 6.0", "velocity_limit = 3.9", 1)
                .replacen("torque_limit = 1.2", "torque_limit = 0.8", 1)
        )
    };
    let robot = Robot::from_str(&reference_robot_path(), &text).unwrap();
    assert_eq!(robot.dxl_model("XL430-W250-7V4").unwrap().stall_torque, 0.9);
    assert_eq!(robot.dxl_protocol_model("XL430-W250-7V4"), "XL430-W250");
    assert_eq!(push_against_the_jig_of(robot, "head_pitch", 0.6, 0.02), 0.8);
}

#[test]
fn a_servo_under_the_models_own_actuator_reads_the_torque_that_acted() {
    // rd-mini's knees are XM430s (Present Current) and its MJCF drives them with position
    // actuators: swinging on the gantry, what the host reads is what MuJoCo applied.
    let root = reference_robot_path()
        .parent()
        .unwrap()
        .parent()
        .unwrap()
        .to_path_buf();
    let robot = Robot::load(&root.join("mini/robot.toml")).unwrap();
    let mut h = host_of(robot, on_gantry());
    let robot = h.robot.clone();
    let j = robot
        .config
        .joints
        .iter()
        .position(|x| x.name == "l_knee")
        .unwrap();
    let a = h.inner.world.lock().unwrap().joint_actuator(j).unwrap();
    let mut pose = h.default_pose.clone();
    let start = h.inner.now();
    let mut worst = 0.0f64;
    for k in 1..=150u32 {
        pose[j] = h.default_pose[j] + 0.4 * (f64::from(k) * 0.05).sin();
        h.inner.command_positions(&robot, &pose).unwrap();
        h.inner.wait_until(start + TICK * k);
        if k > 50 {
            let w = h.inner.world.lock().unwrap();
            let acted = w.data().actuator_force()[a] * w.data().model().actuator_gear()[a][0];
            drop(w);
            worst = worst.max((h.inner.state().tau[j] - acted).abs());
        }
    }
    // The reading is up to a bus cycle older than the physics step compared with: 0.08 N·m apart
    // at most here; the emulated loop's own torque was 0.38 N·m off.
    assert!(
        worst < 0.15,
        "l_knee read up to {worst:.4} N·m off the torque that acted"
    );
}
