//! Robstride motors in their factory protocol: the host driver against emulated motors on a bus
//! they share with an MIT-mode motor (lockstep), the faults a bus sees, a scan, and python-can
//! (an independent client) driving one over socketcand with frames its script packs.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::can::socketcand::SocketcandServer;
use firmware_bridge::can::virtual_bus::{LockstepCanPort, VirtualCanBus};
use firmware_bridge::can::{CanBus, CanFrame};
use firmware_bridge::mit::codec::MotorFault;
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver, MitError, MitJointConfig, scan};
use firmware_bridge::mit::firmware::{InjectedFaults, MitFirmwareConfig};
use firmware_bridge::mit::models::find;
use firmware_bridge::mit::rig::MitRig;
use firmware_bridge::mit::robstride::{self, comm};
use firmware_bridge::plant::InertiaPlant;
use firmware_bridge::time::WallClockRunner;
use test_support::alloc::{CountingAllocator, count_allocations};

#[global_allocator]
static ALLOC: CountingAllocator = CountingAllocator;

const TICK: Duration = Duration::from_millis(20);
const REPLY_TIMEOUT: Duration = Duration::from_millis(2);

/// An AK80-9 (ID 1), an RS03 (ID 2) and an RS00 (ID 3) on one 1 Mbit/s bus.
const MOTORS: [(&str, u8, &str); 3] = [("hip", 1, "AK80-9"), ("knee", 2, "RS03"), ("ankle", 3, "RS00")];

type Driver = MitBusDriver<LockstepCanPort<MitRig>>;

fn setup() -> (Arc<Mutex<MitRig>>, Driver) {
    let mut rig = MitRig::new(
        vec![VirtualCanBus::new("can0", 1_000_000)],
        Duration::from_micros(500),
    );
    let mut joints = Vec::new();
    for (name, id, model) in MOTORS {
        let model = find(model).unwrap();
        rig.add_motor(
            0,
            MitFirmwareConfig::new(id, model),
            InertiaPlant::new(0.02, 0.05, 0.01, 0.0),
        );
        joints.push(MitJointConfig::new(name, id, model));
    }
    let rig = rig.shared();
    let driver = MitBusDriver::new(MitRig::host_port(&rig, 0), joints, REPLY_TIMEOUT).unwrap();
    (rig, driver)
}

fn hold(q: [f64; 3]) -> [JointCommand; 3] {
    q.map(|q| JointCommand {
        q,
        qd: 0.0,
        kp: 40.0,
        kd: 1.0,
        tau: 0.0,
    })
}

/// One 50 Hz tick: a cycle, then the rest of the period.
fn tick(d: &mut Driver, cmds: &[JointCommand]) -> usize {
    let end = d.now() + TICK;
    let missing = d.cycle(cmds).unwrap().missing;
    let port = d.bus_mut();
    while port.now() < end {
        port.recv_until(end).unwrap();
    }
    missing
}

#[test]
fn robstride_and_mit_motors_share_a_bus_under_one_driver() {
    let (rig, mut d) = setup();
    d.enable_all().unwrap();
    let target = [0.4, -0.7, 0.3];
    for _ in 0..100 {
        assert_eq!(tick(&mut d, &hold(target)), 0);
    }
    for (fb, want) in d.feedback().iter().zip(target) {
        assert!((fb.q - want).abs() < 0.01, "{} want {want}", fb.q);
        assert_eq!(fb.fault, MotorFault::None);
    }
    // Robstride reports its mode (run) and temperature; CubeMars no enable state.
    let fb = d.feedback();
    assert_eq!(
        (fb[0].enabled, fb[1].enabled, fb[2].enabled),
        (None, Some(true), Some(true))
    );
    assert!(fb[1].temperature.is_some_and(|t| (20.0..40.0).contains(&t)));
    // The frames on the wire: 29-bit control frames to 2 and 3 carrying the type in bits 24–28.
    let rig = rig.lock().unwrap();
    let shafts: Vec<f64> = rig.motors().iter().map(|m| m.plant.q).collect();
    for (q, want) in shafts.iter().zip(target) {
        assert!((q - want).abs() < 0.02, "{shafts:?}");
    }
    // Steady cycles allocate nothing, Robstride frames included.
    drop(rig);
    let cmds = hold(target);
    let (_, stats) = count_allocations(|| {
        for _ in 0..50 {
            d.cycle(&cmds).unwrap();
        }
    });
    assert!(stats.is_zero(), "{stats:?}");
    d.disable_all().unwrap();
    assert_eq!(d.feedback()[1].enabled, Some(false));
}

#[test]
fn a_motor_left_in_another_run_mode_is_put_back_in_operation_control_on_enable() {
    let (rig, mut d) = setup();
    // Another tool left the RS03 in velocity mode (2): commands would do nothing.
    let mode = robstride::write_param(
        2,
        robstride::DEFAULT_HOST_ID,
        robstride::param::RUN_MODE,
        [2, 0, 0, 0],
    );
    d.bus_mut().send(&mode).unwrap();
    tick(&mut d, &hold([0.0; 3]));
    d.enable_all().unwrap();
    for _ in 0..100 {
        tick(&mut d, &hold([0.0, 0.5, 0.0]));
    }
    assert!((d.feedback()[1].q - 0.5).abs() < 0.01, "{}", d.feedback()[1].q);
    let _ = rig;
}

#[test]
fn a_silent_or_faulted_robstride_marks_only_its_joint_and_foreign_frames_are_counted() {
    let (rig, mut d) = setup();
    d.enable_all().unwrap();
    tick(&mut d, &hold([0.0; 3]));
    rig.lock().unwrap().motor_mut(1).firmware.inject(InjectedFaults {
        silent: true,
        ..InjectedFaults::default()
    });
    let report = d.cycle(&hold([0.0; 3])).unwrap();
    assert_eq!((report.replies, report.missing), (2, 1));
    let fb = d.feedback();
    assert!(fb[1].is_stale() && !fb[0].is_stale() && !fb[2].is_stale());
    let err = d.enable_all().unwrap_err();
    assert!(matches!(err, MitError::NoReply { motor_id: 2, .. }), "{err}");
    rig.lock()
        .unwrap()
        .motor_mut(1)
        .firmware
        .inject(InjectedFaults::default());
    // An overheated RS00: the fault arrives in the feedback frame's identifier.
    rig.lock().unwrap().motor_mut(2).firmware.inject(InjectedFaults {
        fault: Some(MotorFault::OverTemperature),
        ..InjectedFaults::default()
    });
    tick(&mut d, &hold([0.0; 3]));
    tick(&mut d, &hold([0.0; 3]));
    assert_eq!(d.feedback()[2].fault, MotorFault::OverTemperature);
    assert_eq!(d.feedback()[2].enabled, Some(false));
    // Frames the driver does not take: feedback to another host, a parameter answer, a feedback
    // frame naming a motor not on the bus, a short feedback frame.
    let rogue = rig.lock().unwrap().buses()[0].attach();
    let feedback =
        |data2: u16, host: u8| CanFrame::new8(robstride::frame_id(comm::FEEDBACK, data2, host), [0; 8]);
    rogue.send(&feedback(2, 0x01)).unwrap();
    rogue
        .send(&CanFrame::new8(
            robstride::frame_id(comm::READ_PARAM, 2, 0xFD),
            [0; 8],
        ))
        .unwrap();
    rogue.send(&feedback(9, 0xFD)).unwrap();
    rogue
        .send(&CanFrame::new(robstride::frame_id(comm::FEEDBACK, 2, 0xFD), &[0; 4]).unwrap())
        .unwrap();
    let report = d.cycle(&hold([0.0; 3])).unwrap();
    assert_eq!((report.replies, report.rejected), (3, 4));
    let r = d.stats().rejects;
    assert_eq!(
        (r.unknown_id, r.unknown_motor, r.wrong_length),
        (2, 1, 1),
        "{r:?}"
    );
}

#[test]
fn a_scan_finds_robstride_motors_by_their_feedback() {
    let (rig, _) = setup();
    let mut port = MitRig::host_port(&rig, 0);
    let hits = scan(&mut port, find("RS03").unwrap(), 1..=4, REPLY_TIMEOUT).unwrap();
    // The RS03 and the RS00 answer in the factory protocol; the AK80-9 does not speak it.
    assert_eq!(hits.iter().map(|h| h.motor_id).collect::<Vec<_>>(), [2, 3]);
    assert!(
        hits.iter()
            .all(|h| h.reply_id == u16::from(robstride::DEFAULT_HOST_ID))
    );
    assert_eq!(hits[0].reply.enabled, Some(false));
}

#[test]
fn python_can_drives_an_emulated_robstride_over_socketcand() {
    let bus = VirtualCanBus::new("can0", 1_000_000);
    let mut rig = MitRig::new(vec![bus.clone()], Duration::from_micros(500));
    let model = find("RS01").unwrap();
    rig.add_motor(
        0,
        MitFirmwareConfig::new(7, model),
        InertiaPlant::new(0.01, 0.05, 0.0, 0.0),
    );
    let rig = rig.shared();
    let _runner = WallClockRunner::spawn(Arc::clone(&rig), Duration::from_micros(200)).unwrap();
    let clock_start = std::time::Instant::now();
    let server = SocketcandServer::spawn("127.0.0.1:0".parse().unwrap(), "can0", bus.attach(), move || {
        clock_start.elapsed()
    })
    .unwrap();
    let script = test_support::fixtures::workspace_root()
        .join("firmware-bridge/tests/python/robstride_over_socketcand.py");
    let out = std::process::Command::new(test_support::fixtures::venv_python())
        .arg(script)
        .args(["127.0.0.1", &server.local_addr().port().to_string(), "7"])
        .args([model.p_max, model.v_max, model.t_max, model.kp_max, model.kd_max].map(|x| x.to_string()))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "python-can run failed\nstdout: {stdout}\nstderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(v["get_id"]["motor"], 7, "{v}");
    assert_eq!(v["enable"]["mode"], 2, "{v}");
    assert_eq!(v["enable"]["faults"], 0, "{v}");
    assert_eq!(v["run_mode"], 0, "{v}");
    let (p, target) = (v["final"]["p"].as_f64().unwrap(), v["target"].as_f64().unwrap());
    assert!((p - target).abs() < 0.05, "{v}");
    assert_eq!(v["stop"]["mode"], 0, "{v}");
    assert_eq!(server.malformed(), 0);
    assert!(!rig.lock().unwrap().motors()[0].firmware.enabled());
}
