//! The mirrored reference biped, driven through its buses by the real host drivers in lockstep.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::can::virtual_bus::{LockstepCanPort, SimWorld};
use firmware_bridge::dxl::driver::{DxlBusDriver, DxlCommand, DxlDriverOptions};
use firmware_bridge::dxl::transport::LockstepDxlPort;
use firmware_bridge::imu::reader::ImuReader;
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver};
use firmware_bridge::serial::LockstepStream;
use robots::{Robot, drivers, reference_robot_path};
use sim2real::config::{FaultKind, MirrorConfig, Randomization, Range, ScheduledFault};
use sim2real::mirror::Mirror;

const TICK: Duration = Duration::from_millis(20);

struct Host {
    world: Arc<Mutex<Mirror>>,
    mit: Vec<(MitBusDriver<LockstepCanPort<Mirror>>, Vec<usize>)>,
    dxl: DxlBusDriver<LockstepDxlPort<Mirror>>,
    dxl_joints: Vec<usize>,
    imu: ImuReader<LockstepStream<Mirror>>,
    robot: Robot,
}

fn host(config: MirrorConfig) -> Host {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let world = Arc::new(Mutex::new(Mirror::new(robot.clone(), config).unwrap()));
    let ports = Mirror::host_ports(&world);
    let mut mit = Vec::new();
    for (name, port) in ports.can {
        let (idx, joints): (Vec<_>, Vec<_>) = robot
            .joints_on(&name)
            .map(|(i, j)| (i, drivers::mit_joint(j)))
            .unzip();
        let mut d = MitBusDriver::new(port, joints, Duration::from_millis(2)).unwrap();
        d.enable_all().unwrap();
        mit.push((d, idx));
    }
    let (name, port) = ports.dxl.into_iter().next().unwrap();
    let (dxl_joints, joints): (Vec<_>, Vec<_>) = robot
        .joints_on(&name)
        .map(|(i, j)| (i, drivers::dxl_joint(j)))
        .unzip();
    let options = DxlDriverOptions {
        expected_return_delay: Duration::ZERO,
        ..DxlDriverOptions::default()
    };
    let mut dxl = DxlBusDriver::new(port, joints, options).unwrap();
    dxl.configure().unwrap();
    dxl.enable().unwrap();
    Host {
        world,
        mit,
        dxl,
        dxl_joints,
        imu: ImuReader::new(ports.imu),
        robot,
    }
}

impl Host {
    /// One control tick holding the default pose; returns the joint angles the buses reported.
    fn hold_default_pose(&mut self, log: &mut Vec<u64>) {
        let joints = &self.robot.config.joints;
        for (d, idx) in &mut self.mit {
            let cmds: Vec<_> = idx
                .iter()
                .map(|&i| JointCommand {
                    q: joints[i].default_position,
                    qd: 0.0,
                    kp: joints[i].kp,
                    kd: joints[i].kd,
                    tau: 0.0,
                })
                .collect();
            d.cycle(&cmds).unwrap();
            log.extend(d.feedback().iter().map(|f| f.q.to_bits()));
        }
        let cmds: Vec<_> = self
            .dxl_joints
            .iter()
            .map(|&i| DxlCommand {
                q: joints[i].default_position,
                current: 0.0,
            })
            .collect();
        self.dxl.cycle(&cmds).unwrap();
        log.extend(self.dxl.feedback().iter().map(|f| f.q.to_bits()));
        if let Some(r) = self.imu.poll().unwrap() {
            log.extend(r.sample.gyro.map(f64::to_bits));
            log.extend(r.sample.quat.map(f64::to_bits));
        }
    }

    fn run(&mut self, seconds: f64) -> Vec<u64> {
        let mut log = Vec::new();
        let ticks = (seconds / TICK.as_secs_f64()).round() as u32;
        let start = self.world.lock().unwrap().now();
        for k in 1..=ticks {
            self.hold_default_pose(&mut log);
            let mut w = self.world.lock().unwrap();
            let target = start + TICK * k;
            while w.now() < target {
                w.step_until(target);
            }
        }
        log
    }
}

#[test]
fn the_biped_stands_ten_seconds_under_its_own_firmware_pd() {
    let mut h = host(MirrorConfig::default());
    let start = h.world.lock().unwrap().root_pose();
    for _ in 0..20 {
        h.run(0.5);
        let w = h.world.lock().unwrap();
        eprintln!(
            "t={:?} root={:?} ncon={}",
            w.now(),
            w.root_pose(),
            w.data().ffi().ncon
        );
    }
    let w = h.world.lock().unwrap();
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
    let imu = h.imu.poll().unwrap().unwrap();
    assert!((imu.sample.accel[2] - 9.81).abs() < 1.0, "{:?}", imu.sample.accel);
}

#[test]
fn on_the_gantry_the_feet_stay_off_the_floor_and_the_pose_holds() {
    let mut h = host(MirrorConfig {
        gantry: true,
        ..MirrorConfig::default()
    });
    let start = h.world.lock().unwrap().root_pose();
    h.run(3.0);
    let w = h.world.lock().unwrap();
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
    assert!(h.dxl.feedback().iter().all(|f| !f.is_stale()));
    h.run(0.2);
    let elbow = h
        .dxl_joints
        .iter()
        .position(|&i| h.robot.config.joints[i].name == "left_elbow")
        .unwrap();
    assert!(h.dxl.feedback()[elbow].is_stale());
    let (right, idx) = &h.mit[1];
    let knee = idx
        .iter()
        .position(|&i| h.robot.config.joints[i].name == "right_knee")
        .unwrap();
    assert!(right.feedback()[knee].is_stale());
    assert_eq!(h.world.lock().unwrap().stats().faults_applied, 2);
}

#[test]
fn a_robot_whose_model_lacks_imu_sensors_is_refused_by_name() {
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let dir = std::env::temp_dir().join(format!("mirror-nosensor-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let xml = std::fs::read_to_string(&robot.mjcf_path)
        .unwrap()
        .replace("name=\"imu_gyro\"", "name=\"gyro\"");
    std::fs::write(dir.join("biped.xml"), xml).unwrap();
    let text = std::fs::read_to_string(reference_robot_path()).unwrap();
    let robot = Robot::from_str(&dir.join("robot.toml"), &text).unwrap();
    let e = Mirror::new(robot, MirrorConfig::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("no sensor \"imu_gyro\""), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}
