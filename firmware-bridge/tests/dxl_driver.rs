//! The Dynamixel host driver against emulated X-series servos, in lockstep simulated time.

use std::f64::consts::PI;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::dxl::driver::{
    DxlBusDriver, DxlCommand, DxlDriverOptions, DxlError, DxlFault, DxlJointConfig, DxlMode, ScanProblem,
};
use firmware_bridge::dxl::models::find;
use firmware_bridge::dxl::servo::ReplyFault;
use firmware_bridge::dxl::table::{addr, hw};
use firmware_bridge::dxl::transport::LockstepDxlPort;
use firmware_bridge::dxl::wire::{DxlRig, WireTiming};
use firmware_bridge::time::SimInstant;
use firmware_bridge::time::SimWorld;
use test_support::alloc::{CountingAllocator, count_allocations};

#[global_allocator]
static ALLOC: CountingAllocator = CountingAllocator;

const BAUD: u32 = 1_000_000;
const TICK: Duration = Duration::from_millis(20);

type Driver = DxlBusDriver<LockstepDxlPort<DxlRig>>;

/// `models[i]` servos with IDs 1.., each on a small arm link, their joints' zero at `zero[i]` ticks.
fn rig(models: &[&str]) -> Arc<Mutex<DxlRig>> {
    let servos: Vec<_> = models
        .iter()
        .enumerate()
        .map(|(i, m)| (i as u8 + 1, find(m).unwrap()))
        .collect();
    Arc::new(Mutex::new(DxlRig::bench(
        &servos,
        WireTiming::new(BAUD),
        Duration::from_micros(500),
    )))
}

fn joints(models: &[&str]) -> Vec<DxlJointConfig> {
    models
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let mut j = DxlJointConfig::new(&format!("joint{}", i + 1), i as u8 + 1, m);
            j.direction = if i % 2 == 0 { 1.0 } else { -1.0 };
            j.zero_ticks = 2048.0 + 100.0 * i as f64;
            j
        })
        .collect()
}

fn driver(world: &Arc<Mutex<DxlRig>>, joints: Vec<DxlJointConfig>) -> Driver {
    let port = LockstepDxlPort::new(Arc::clone(world), 0, BAUD);
    DxlBusDriver::new(port, joints, DxlDriverOptions::default()).unwrap()
}

/// Runs the world to the next control tick.
fn wait_tick(world: &Arc<Mutex<DxlRig>>, start: SimInstant, k: u32) {
    let mut w = world.lock().unwrap();
    let target = start + TICK * k;
    while w.now() < target {
        w.step_until(target);
    }
}

fn ready(models: &[&str]) -> (Arc<Mutex<DxlRig>>, Driver) {
    let world = rig(models);
    let mut d = driver(&world, joints(models));
    d.configure().unwrap();
    d.enable().unwrap();
    (world, d)
}

#[test]
fn joints_track_goals_in_joint_units_through_sync_write_and_sync_read() {
    let models = ["XM430-W350", "XM430-W350", "XL430-W250", "XM430-W350"];
    let (world, mut d) = ready(&models);
    let start = world.lock().unwrap().now();
    let goals = [0.5, -0.3, 0.8, 0.0];
    let commands: Vec<_> = goals.iter().map(|&q| DxlCommand { q, current: 1.0 }).collect();
    for k in 1..=50 {
        let report = d.cycle(&commands).unwrap();
        assert_eq!((report.fresh, report.first_fault), (4, None));
        wait_tick(&world, start, k);
    }
    let w = world.lock().unwrap();
    for (i, (fb, goal)) in d.feedback().iter().zip(goals).enumerate() {
        assert!(
            (fb.q - goal).abs() < 0.02,
            "joint {i}: q = {} for goal {goal}",
            fb.q
        );
        assert!(fb.qd.abs() < 0.2, "joint {i} still moving: {}", fb.qd);
        assert!((fb.voltage - 12.0).abs() < 1e-9 && fb.temperature >= 25.0);
        // The plant angle agrees with the joint angle through direction and zero offset.
        let j = &d.joints()[i];
        let shaft = (f64::from(j.rad_to_ticks(fb.q)) - 2048.0) * 2.0 * PI / 4096.0;
        assert!(
            (shaft - w.plants()[i].q).abs() < 0.01,
            "joint {i}: shaft {shaft} vs plant {}",
            w.plants()[i].q
        );
    }
    assert!(d.feedback()[0].current.is_some() && d.feedback()[2].current.is_none());
}

#[test]
fn a_cycle_takes_the_modelled_wire_time() {
    let models = ["XM430-W350"; 4];
    let (world, mut d) = ready(&models);
    let commands = vec![DxlCommand::default(); 4];
    let t0 = world.lock().unwrap().now();
    d.cycle(&commands).unwrap();
    let took = world.lock().unwrap().now() - t0;
    // Sync write 10+4+4·7 = 42 bytes, sync read 10+4+4 = 18 bytes, 4 status packets of 11+16;
    // the driver set Return Delay Time to 0.
    let bytes = 42 + 18 + 4 * 27;
    let wire = WireTiming::new(BAUD).bytes_time(bytes);
    assert!(
        took >= wire && took < wire + Duration::from_micros(600),
        "cycle took {took:?}, wire {wire:?}"
    );
}

#[test]
fn scan_names_missing_and_mismatched_servos_and_enables_nothing() {
    let world = rig(&["XM430-W350", "XL430-W250"]);
    let mut cfg = joints(&["XM430-W350", "XM430-W350"]);
    cfg.push(DxlJointConfig::new("ghost", 9, "XM430-W350"));
    let mut d = driver(&world, cfg);
    let err = d.configure().unwrap_err();
    let DxlError::Scan(problems) = &err else {
        panic!("{err}")
    };
    assert_eq!(problems.len(), 2);
    assert!(matches!(
        &problems[0],
        ScanProblem::WrongModel {
            id: 2,
            found: 1060,
            ..
        }
    ));
    assert!(matches!(&problems[1], ScanProblem::Missing { id: 9, .. }));
    let text = err.to_string();
    assert!(
        text.contains("servo 2 (joint2): configured as XM430-W350, but it is model 1060 (XL430-W250)"),
        "{text}"
    );
    assert!(text.contains("servo 9 (ghost): no answer"), "{text}");
    let w = world.lock().unwrap();
    assert!(!w.servo(0).torque_enabled() && !w.servo(1).torque_enabled());
}

#[test]
fn bad_configurations_are_refused_with_the_joint_named() {
    let world = rig(&["XL430-W250"]);
    let port = || LockstepDxlPort::new(Arc::clone(&world), 0, BAUD);
    let mut j = DxlJointConfig::new("wrist", 1, "XL430-W250");
    j.mode = DxlMode::CurrentBasedPosition;
    let e = DxlBusDriver::new(port(), vec![j], DxlDriverOptions::default()).unwrap_err();
    assert!(
        e.to_string()
            .contains("\"wrist\": XL430-W250 has no current sensing"),
        "{e}"
    );
    let e = DxlBusDriver::new(
        port(),
        vec![DxlJointConfig::new("x", 1, "MX-28")],
        DxlDriverOptions::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("model \"MX-28\" is not one of"), "{e}");
    let two = vec![
        DxlJointConfig::new("a", 1, "XL430-W250"),
        DxlJointConfig::new("b", 1, "XL430-W250"),
    ];
    let e = DxlBusDriver::new(port(), two, DxlDriverOptions::default()).unwrap_err();
    assert!(e.to_string().contains("share id 1"), "{e}");
}

#[test]
fn non_finite_commands_never_reach_the_wire() {
    let (world, mut d) = ready(&["XM430-W350"; 2]);
    let before = world.lock().unwrap().wire().chain().stats().packets;
    let e = d
        .write_goals(&[
            DxlCommand::default(),
            DxlCommand {
                q: f64::NAN,
                current: 0.0,
            },
        ])
        .unwrap_err();
    assert!(
        e.to_string().contains("\"joint2\": non-finite command refused"),
        "{e}"
    );
    let mut w = world.lock().unwrap();
    let t = w.now() + Duration::from_millis(5);
    w.step_until(t);
    assert_eq!(w.wire().chain().stats().packets, before);
}

#[test]
fn transient_reply_faults_are_typed_per_servo_mark_feedback_stale_and_clear() {
    let models = ["XM430-W350"; 4];
    let (world, mut d) = ready(&models);
    let commands = vec![DxlCommand::default(); 4];
    let start = world.lock().unwrap().now();
    d.cycle(&commands).unwrap();
    type Expect = fn(&DxlFault) -> bool;
    let cases: [(usize, ReplyFault, Expect); 4] = [
        (1, ReplyFault::Silent, |f| *f == DxlFault::NoReply { id: 2 }),
        (2, ReplyFault::CorruptCrc, |f| *f == DxlFault::Crc { id: 3 }),
        (3, ReplyFault::WrongId(7), |f| {
            *f == DxlFault::WrongId { expected: 4, got: 7 }
        }),
        (0, ReplyFault::Delay(Duration::from_millis(30)), |f| {
            matches!(f, DxlFault::NoReply { .. })
        }),
    ];
    for (k, (servo, fault, expected)) in cases.into_iter().enumerate() {
        world.lock().unwrap().servo_mut(servo).inject(fault, Some(1));
        wait_tick(&world, start, 2 * k as u32 + 1);
        let report = d.cycle(&commands).unwrap();
        let f = d.feedback()[servo]
            .last_fault
            .expect("the faulty servo has a fault");
        assert!(expected(&f), "{fault:?} gave {f:?}");
        assert_eq!(f.id(), servo as u8 + 1);
        assert!(d.feedback()[servo].is_stale());
        assert!(report.stale >= 1 && report.first_fault.is_some());
        // The next cycle is clean: the bus stays usable after a transient fault.
        wait_tick(&world, start, 2 * k as u32 + 2);
        let report = d.cycle(&commands).unwrap();
        assert_eq!((report.fresh, report.first_fault), (4, None), "after {fault:?}");
    }
}

#[test]
fn a_vanished_servo_stays_stale_while_the_others_keep_working() {
    let (world, mut d) = ready(&["XM430-W350"; 3]);
    let commands = vec![DxlCommand { q: 0.2, current: 0.0 }; 3];
    let start = world.lock().unwrap().now();
    world.lock().unwrap().servo_mut(1).vanish();
    for k in 1..=10 {
        let report = d.cycle(&commands).unwrap();
        assert_eq!(report.fresh, 2);
        assert_eq!(d.feedback()[1].last_fault, Some(DxlFault::NoReply { id: 2 }));
        assert!(!d.feedback()[0].is_stale() && !d.feedback()[2].is_stale());
        wait_tick(&world, start, k);
    }
    assert!(d.feedback()[1].missed_cycles >= 10);
}

#[test]
fn overheating_shuts_the_servo_down_until_a_reboot_recovers_it() {
    let (world, mut d) = ready(&["XM430-W350"; 2]);
    let commands = vec![DxlCommand { q: 0.3, current: 0.0 }; 2];
    world
        .lock()
        .unwrap()
        .servo_mut(0)
        .raise_hardware_error(hw::OVERHEAT);
    let report = d.cycle(&commands).unwrap();
    assert_eq!(
        report.first_fault,
        Some(DxlFault::Hardware {
            id: 1,
            bits: hw::OVERHEAT
        })
    );
    assert!(!d.feedback()[0].is_stale(), "state is still valid");
    assert!(!world.lock().unwrap().servo(0).torque_enabled());
    // Torque cannot come back while the shutdown holds.
    assert!(matches!(
        d.enable(),
        Err(DxlError::Fault(DxlFault::Hardware { id: 1, .. }))
    ));
    d.recover(0, Duration::from_secs(1)).unwrap();
    assert_eq!(world.lock().unwrap().servo(0).hardware_error(), 0);
    d.enable().unwrap();
    let report = d.cycle(&commands).unwrap();
    assert_eq!((report.fresh, report.first_fault), (2, None));
}

#[test]
fn the_bus_watchdog_drops_torque_when_the_host_goes_quiet() {
    let (world, mut d) = ready(&["XM430-W350"; 2]);
    let commands = vec![DxlCommand::default(); 2];
    d.cycle(&commands).unwrap();
    {
        let mut w = world.lock().unwrap();
        let t = w.now() + Duration::from_millis(150);
        while w.now() < t {
            w.step_until(t);
        }
        // Default watchdog 100 ms.
        assert!(!w.servo(0).torque_enabled() && !w.servo(1).torque_enabled());
        assert_eq!(w.servo(0).register(addr::BUS_WATCHDOG), -1);
    }
    d.disable().unwrap();
    d.enable().unwrap();
    assert!(world.lock().unwrap().servo(0).torque_enabled());
}

#[test]
fn the_steady_state_cycle_does_not_allocate() {
    let (world, mut d) = ready(&["XM430-W350"; 8]);
    let commands = vec![DxlCommand { q: 0.1, current: 0.5 }; 8];
    let start = world.lock().unwrap().now();
    for k in 1..=5 {
        d.cycle(&commands).unwrap();
        wait_tick(&world, start, k);
    }
    let (_, stats) = count_allocations(|| {
        for k in 6..=25 {
            d.cycle(&commands).unwrap();
            wait_tick(&world, start, k);
        }
    });
    assert!(stats.is_zero(), "{stats:?}");
}

/// Like `ready`, the driver reading the state with Fast Sync Read.
fn ready_fast(models: &[&str]) -> (Arc<Mutex<DxlRig>>, Driver) {
    let world = rig(models);
    let port = LockstepDxlPort::new(Arc::clone(&world), 0, BAUD);
    let options = DxlDriverOptions {
        fast_reads: true,
        ..DxlDriverOptions::default()
    };
    let mut d = DxlBusDriver::new(port, joints(models), options).unwrap();
    d.configure().unwrap();
    d.enable().unwrap();
    (world, d)
}

#[test]
fn fast_reads_read_every_servo_in_one_packet_and_a_fault_costs_only_its_servo() {
    let models = ["XM430-W350"; 4];
    let (world, mut d) = ready_fast(&models);
    let commands = vec![DxlCommand { q: 0.1, current: 0.0 }; 4];
    let start = world.lock().unwrap().now();
    for k in 1..=5 {
        assert_eq!(d.cycle(&commands).unwrap().fresh, 4);
        wait_tick(&world, start, k);
    }
    assert_eq!(d.stats().fast_reads, 5);
    // A silent servo in the middle: its slot stays empty, the ones after it are read where they
    // are; a corrupt CRC costs that servo only (the CRC chain runs over what was on the wire).
    type Expect = fn(&DxlFault) -> bool;
    let cases: [(usize, ReplyFault, Expect); 3] = [
        (1, ReplyFault::Silent, |f| *f == DxlFault::NoReply { id: 2 }),
        (2, ReplyFault::CorruptCrc, |f| *f == DxlFault::Crc { id: 3 }),
        // The first servo sends the packet's header: without it the cycle's fast packet is lost.
        (0, ReplyFault::Silent, |f| *f == DxlFault::NoReply { id: 1 }),
    ];
    let mut tick = 5;
    for (servo, fault, expected) in cases {
        world.lock().unwrap().servo_mut(servo).inject(fault, Some(1));
        tick += 1;
        wait_tick(&world, start, tick);
        let report = d.cycle(&commands).unwrap();
        let f = d.feedback()[servo].last_fault.expect("a fault");
        assert!(expected(&f), "{fault:?} gave {f:?}");
        if servo != 0 {
            // Everyone else was read from the same packet.
            assert_eq!(report.fresh, 3, "{fault:?}");
        }
        // Then plain sync reads for a while: every servo answers on its own.
        let fast_before = d.stats().fast_reads;
        tick += 1;
        wait_tick(&world, start, tick);
        assert_eq!(d.cycle(&commands).unwrap().fresh, 4);
        assert_eq!(d.stats().fast_reads, fast_before, "backed off to sync reads");
        // Past the back-off, fast again.
        for _ in 0..firmware_bridge::dxl::driver::FAST_READ_BACKOFF {
            tick += 1;
            wait_tick(&world, start, tick);
            d.cycle(&commands).unwrap();
        }
        assert_eq!(d.stats().fast_reads, fast_before + 1);
    }
}

#[test]
fn a_steady_fast_read_cycle_allocates_nothing() {
    let (world, mut d) = ready_fast(&["XM430-W350"; 8]);
    let commands = vec![DxlCommand { q: 0.1, current: 0.0 }; 8];
    let start = world.lock().unwrap().now();
    for k in 1..=5 {
        d.cycle(&commands).unwrap();
        wait_tick(&world, start, k);
    }
    let (_, stats) = count_allocations(|| {
        for k in 6..=25 {
            assert_eq!(d.cycle(&commands).unwrap().fresh, 8);
            wait_tick(&world, start, k);
        }
    });
    assert!(stats.is_zero(), "{stats:?}");
}
