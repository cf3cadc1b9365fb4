//! The mirror served in wall-clock time: the unmodified drivers reach it over socketcand (CAN) and
//! pseudo-terminals (Dynamixel, IMU), as they would reach the robot.

use std::net::{IpAddr, Ipv4Addr};
use std::time::{Duration, Instant};

use firmware_bridge::can::socketcand::SocketcandClient;
use firmware_bridge::dxl::driver::{DxlBusDriver, DxlCommand, DxlDriverOptions};
use firmware_bridge::dxl::transport::SerialDxlPort;
use firmware_bridge::imu::reader::ImuReader;
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver};
use firmware_bridge::serial::DeviceStream;
use robots::{Robot, drivers, reference_robot_path};
use sim2real::config::MirrorConfig;
use sim2real::mirror::Mirror;
use sim2real::serve::ServedMirror;

#[test]
fn drivers_hold_the_served_biped_over_socketcand_and_pseudo_terminals() {
    // In real time beside the test's own driving: a host starved by other work may time out a
    // motor (correctly); such an attempt is measured, said and tried again.
    if let Some(held) = test_support::starvation::judged_unstarved(
        "driving the served biped",
        hold_the_served_biped,
        Result::is_ok,
    ) {
        held.unwrap();
    }
}

/// Drives the served biped's default pose for 1.5 s over its real wires; what went wrong.
fn hold_the_served_biped() -> Result<(), String> {
    // This host loop cycles every 20 ms on a shared machine: the motors get a command timeout
    // (200 ms) that a starved test thread cannot outlast, instead of the 40 ms of the robot's own
    // 250 Hz buses.
    let text = std::fs::read_to_string(reference_robot_path()).unwrap().replace(
        "kind = \"mit_can\"",
        "kind = \"mit_can\"\ncommand_timeout_ms = 200.0",
    );
    let robot = Robot::from_str(&reference_robot_path(), &text).unwrap();
    let mirror = Mirror::new(
        robot.clone(),
        MirrorConfig {
            gantry: true,
            ..MirrorConfig::default()
        },
    )
    .unwrap();
    let served = ServedMirror::start(mirror, IpAddr::V4(Ipv4Addr::LOCALHOST), 0).unwrap();
    let ep = served.endpoints().clone();
    assert_eq!((ep.can.len(), ep.dxl.len()), (2, 1));
    assert!(ep.can.iter().all(|(_, a)| a.ip().is_loopback()));

    let joints = &robot.config.joints;
    let mut mit = Vec::new();
    for (name, addr) in &ep.can {
        let client = SocketcandClient::connect(addr, name, Duration::from_secs(2)).unwrap();
        let (idx, cfg): (Vec<_>, Vec<_>) = robot
            .joints_on(name)
            .map(|(i, j)| (i, drivers::mit_joint(&robot, j)))
            .unzip();
        let mut d = MitBusDriver::new(client, cfg, Duration::from_millis(20)).unwrap();
        d.enable_all().unwrap();
        mit.push((d, idx));
    }
    let (name, path) = &ep.dxl[0];
    let rate = robot.bus(name).unwrap().rate;
    let (dxl_idx, cfg): (Vec<_>, Vec<_>) = robot
        .joints_on(name)
        .map(|(i, j)| (i, drivers::dxl_joint(&robot, j)))
        .unzip();
    let options = DxlDriverOptions {
        reply_slack: Duration::from_millis(30),
        ..DxlDriverOptions::default()
    };
    let mut dxl = DxlBusDriver::new(SerialDxlPort::open(path, rate).unwrap(), cfg, options).unwrap();
    dxl.configure().unwrap();
    dxl.enable().unwrap();
    let imu_rate = robot.bus(&robot.config.imu.bus).unwrap().rate;
    let mut imu = ImuReader::new(DeviceStream::open(ep.imu.as_deref().unwrap(), imu_rate).unwrap());

    let start = Instant::now();
    let mut imu_samples = 0;
    while start.elapsed() < Duration::from_millis(1500) {
        for (d, idx) in &mut mit {
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
            d.cycle(&cmds).map_err(|e| format!("MIT cycle: {e}"))?;
        }
        let cmds: Vec<_> = dxl_idx
            .iter()
            .map(|&i| DxlCommand {
                q: joints[i].default_position,
                current: drivers::goal_current_for(
                    joints[i].torque_limit,
                    firmware_bridge::dxl::models::find(&joints[i].model).unwrap(),
                ),
            })
            .collect();
        dxl.cycle(&cmds).map_err(|e| format!("Dynamixel cycle: {e}"))?;
        if imu.poll().map_err(|e| format!("IMU: {e}"))?.is_some() {
            imu_samples += 1;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    for (d, idx) in &mit {
        for (f, &i) in d.feedback().iter().zip(idx) {
            if (f.q - joints[i].default_position).abs() >= 0.1 {
                return Err(format!("{}: {}", joints[i].name, f.q));
            }
        }
    }
    for (f, &i) in dxl.feedback().iter().zip(&dxl_idx) {
        if f.is_stale() || (f.q - joints[i].default_position).abs() >= 0.1 {
            return Err(format!("{}: {f:?}", joints[i].name));
        }
    }
    let sample = imu
        .poll()
        .map_err(|e| format!("IMU: {e}"))?
        .ok_or("no IMU sample arrived")?
        .sample;
    if !(imu_samples > 10 && (sample.accel[2] - 9.81).abs() < 1.0) {
        return Err(format!("{imu_samples} IMU samples, last {sample:?}"));
    }
    // A corrupted byte is a fault of the wire, whatever the load.
    assert_eq!(imu.stats().checksum_errors, 0);
    Ok(())
}

/// A served mirror's clock measures how far the simulation is behind real time: a mirror whose
/// physics does not run (a host too busy to step it) falls behind by the wall time that passed,
/// and a run's ground truth says so.
#[test]
fn a_mirror_that_does_not_keep_up_is_measured_behind_real_time() {
    use robot_link::{GroundTruth, TickClock};
    let robot = Robot::load(&reference_robot_path()).unwrap();
    let mirror = Mirror::new(robot, MirrorConfig::default()).unwrap();
    let world = std::sync::Arc::new(std::sync::Mutex::new(mirror));
    // No runner steps this world: its simulated time stands still, so it is behind by exactly
    // the wall time since the clock started (read between the two wall readings around it).
    let clock = sim2real::link::ServedClock::new(std::sync::Arc::clone(&world));
    let mut truth = GroundTruth::default();
    let before = clock.elapsed();
    assert!(clock.ground_truth(&mut truth));
    let after = clock.elapsed();
    assert!(
        truth.mirror_behind >= before && truth.mirror_behind <= after && after > Duration::ZERO,
        "{:?} behind, read between {before:?} and {after:?}",
        truth.mirror_behind
    );
    // Stepped up to the wall clock, it is on time again.
    {
        use firmware_bridge::time::SimWorld;
        let mut w = world.lock().unwrap();
        let target = w.now() + clock.elapsed() + Duration::from_millis(5);
        while w.now() < target {
            w.step_until(target);
        }
    }
    assert!(clock.ground_truth(&mut truth));
    assert_eq!(truth.mirror_behind, Duration::ZERO);
}
