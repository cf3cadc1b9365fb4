//! The MIT host driver against emulated motors on virtual buses, in lockstep simulated time.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::can::virtual_bus::{
    CanFaultKind, CanFaultPlan, CanFaultRule, LockstepCanPort, VirtualCanBus,
};
use firmware_bridge::can::{CanBus, CanError, CanFrame, CanId};
use firmware_bridge::mit::codec::MotorFault;
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver, MitError, MitJointConfig};
use firmware_bridge::mit::firmware::{InjectedFaults, MitFirmwareConfig};
use firmware_bridge::mit::models::find;
use firmware_bridge::mit::rig::MitRig;
use firmware_bridge::plant::InertiaPlant;
use firmware_bridge::time::SimInstant;
use test_support::alloc::{CountingAllocator, count_allocations};

#[global_allocator]
static ALLOC: CountingAllocator = CountingAllocator;

const TICK: Duration = Duration::from_millis(20);
const REPLY_TIMEOUT: Duration = Duration::from_millis(2);

struct Joint {
    name: &'static str,
    id: u8,
    model: &'static str,
    direction: f64,
    offset: f64,
    gear: f64,
}

const LEG: [Joint; 3] = [
    Joint {
        name: "hip_pitch",
        id: 1,
        model: "AK80-9",
        direction: 1.0,
        offset: 0.2,
        gear: 1.0,
    },
    Joint {
        name: "knee",
        id: 2,
        model: "AK10-9",
        direction: -1.0,
        offset: -0.1,
        gear: 1.5,
    },
    Joint {
        name: "ankle",
        id: 3,
        model: "DM-J4340",
        direction: 1.0,
        offset: 0.0,
        gear: 2.0,
    },
];

type Driver = MitBusDriver<LockstepCanPort<MitRig>>;

/// One rig with two buses, the leg on each, and a driver per bus.
fn setup(faults: [CanFaultPlan; 2]) -> (Arc<Mutex<MitRig>>, Vec<Driver>) {
    let [f0, f1] = faults;
    let buses = vec![
        VirtualCanBus::with_faults("can0", 1_000_000, f0),
        VirtualCanBus::with_faults("can1", 1_000_000, f1),
    ];
    let mut rig = MitRig::new(buses, Duration::from_micros(500));
    let mut configs = [Vec::new(), Vec::new()];
    for (bus, config) in configs.iter_mut().enumerate() {
        for j in &LEG {
            let model = find(j.model).unwrap();
            let fw = MitFirmwareConfig::new(j.id, model);
            // The motor's shaft starts where joint zero is.
            rig.add_motor(bus, fw.clone(), InertiaPlant::new(0.01, 0.05, 0.01, j.offset));
            config.push(MitJointConfig {
                direction: j.direction,
                offset: j.offset,
                gear_ratio: j.gear,
                ..MitJointConfig::new(&format!("{}_{bus}", j.name), j.id, model)
            });
        }
    }
    let rig = rig.shared();
    let drivers = configs
        .into_iter()
        .enumerate()
        .map(|(bus, cfg)| MitBusDriver::new(MitRig::host_port(&rig, bus), cfg, REPLY_TIMEOUT).unwrap())
        .collect();
    (rig, drivers)
}

/// Runs one 50 Hz tick on every driver, then waits out the rest of the period.
fn tick(
    rig: &Arc<Mutex<MitRig>>,
    drivers: &mut [Driver],
    cmds: &[JointCommand],
) -> Vec<Result<usize, MitError>> {
    let start = drivers[0].now();
    let out = drivers
        .iter_mut()
        .map(|d| d.cycle(cmds).map(|r| r.missing))
        .collect();
    let end = start + TICK;
    let port = drivers[0].bus_mut();
    while port.now() < end {
        port.recv_until(end).unwrap();
    }
    let _ = rig;
    out
}

fn hold(q: [f64; 3]) -> [JointCommand; 3] {
    q.map(|q| JointCommand {
        q,
        qd: 0.0,
        kp: 30.0,
        kd: 1.0,
        tau: 0.0,
    })
}

#[test]
fn two_buses_track_joint_targets_through_direction_offset_and_gear() {
    let (rig, mut drivers) = setup(Default::default());
    for d in &mut drivers {
        d.enable_all().unwrap();
    }
    let target = [0.3, -0.6, 0.25];
    for _ in 0..100 {
        for r in tick(&rig, &mut drivers, &hold(target)) {
            assert_eq!(r.unwrap(), 0, "every motor answers every tick");
        }
    }
    for d in &drivers {
        for (fb, want) in d.feedback().iter().zip(target) {
            assert!((fb.q - want).abs() < 0.01, "joint at {} want {want}", fb.q);
            assert_eq!((fb.missed_cycles, fb.fault), (0, MotorFault::None));
        }
        // Only DaMiao replies carry the enable state.
        assert_eq!(
            d.feedback().iter().map(|f| f.enabled).collect::<Vec<_>>(),
            [None, None, Some(true)]
        );
    }
    // The motor shafts moved the way each joint's direction, offset and gear say.
    let rig = rig.lock().unwrap();
    for (m, (j, want)) in rig.motors().iter().zip(LEG.iter().zip(target).cycle()) {
        let shaft = j.direction * j.gear * want + j.offset;
        assert!(
            (m.plant.q - shaft).abs() < 0.02,
            "{}: shaft {} want {shaft}",
            j.name,
            m.plant.q
        );
    }
    // Simulated time advanced by exactly the ticks run (plus enable), not by wall time.
    assert!(rig.buses()[0].now() >= SimInstant::ZERO + TICK * 100);
}

#[test]
fn a_silent_motor_is_detected_within_one_tick_and_the_tick_stays_bounded() {
    let (rig, mut drivers) = setup(Default::default());
    drivers[0].enable_all().unwrap();
    tick(&rig, &mut drivers[..1], &hold([0.0; 3]));
    rig.lock().unwrap().motor_mut(1).firmware.inject(InjectedFaults {
        silent: true,
        ..InjectedFaults::default()
    });
    let before = drivers[0].now();
    let report = drivers[0].cycle(&hold([0.0; 3])).unwrap();
    let spent = drivers[0].now() - before;
    assert_eq!((report.replies, report.missing), (2, 1));
    assert!(
        spent <= REPLY_TIMEOUT + Duration::from_micros(1),
        "the cycle waited {spent:?}"
    );
    let fb = drivers[0].feedback();
    assert!(fb[1].is_stale() && !fb[0].is_stale() && !fb[2].is_stale());
    tick(&rig, &mut drivers[..1], &hold([0.0; 3]));
    let fb = &drivers[0].feedback()[1];
    assert_eq!(fb.missed_cycles, 2);
    assert!(fb.age(drivers[0].now()).unwrap() >= TICK, "age is reported");
    // A motor that never answered fails enable by name.
    let err = drivers[0].enable_all().unwrap_err();
    assert!(matches!(err, MitError::NoReply { motor_id: 2, .. }), "{err}");
    assert!(err.to_string().contains("knee_0"), "{err}");
}

#[test]
fn dropped_delayed_and_corrupted_frames_mark_only_their_joint() {
    let rule = |id: u16, kind| CanFaultRule {
        id: CanId::standard(id),
        from: SimInstant::ZERO,
        until: None,
        probability: 1.0,
        kind,
    };
    let plan = CanFaultPlan {
        rules: vec![
            // Motor 1's commands are lost, motor 3's arrive after the reply window; CRC errors on
            // motor 2 only cost a retransmission.
            rule(1, CanFaultKind::Drop),
            rule(3, CanFaultKind::Delay(Duration::from_millis(5))),
            rule(2, CanFaultKind::CrcError),
        ],
        ..CanFaultPlan::default()
    };
    let (rig, mut drivers) = setup([plan, CanFaultPlan::default()]);
    let report = drivers[0].cycle(&hold([0.0; 3])).unwrap();
    assert_eq!((report.replies, report.missing), (1, 2));
    let fb = drivers[0].feedback();
    assert!(fb[0].is_stale() && !fb[1].is_stale() && fb[2].is_stale());
    // The late reply arrives during the next cycle and is not mistaken for a fresh one.
    tick(&rig, &mut drivers[..1], &hold([0.0; 3]));
    let stats = rig.lock().unwrap().buses()[0].stats();
    assert!(stats.dropped >= 1 && stats.delayed >= 2, "{stats:?}");
}

#[test]
fn malformed_and_foreign_frames_are_counted_never_fatal() {
    let (rig, mut drivers) = setup(Default::default());
    let rogue = rig.lock().unwrap().buses()[0].attach();
    // Wrong DLC on a reply ID, an unknown ID, a reply naming a motor not on this bus, an extended ID.
    rogue
        .send(&CanFrame::new(CanId::Standard(0), &[1, 2, 3]).unwrap())
        .unwrap();
    rogue
        .send(&CanFrame::new8(CanId::Standard(0x555), [0; 8]))
        .unwrap();
    rogue
        .send(&CanFrame::new8(CanId::Standard(0), [9, 0, 0, 0, 0, 0, 0, 0]))
        .unwrap();
    rogue
        .send(&CanFrame::new8(CanId::Extended(0x1234), [0; 8]))
        .unwrap();
    let report = drivers[0].cycle(&hold([0.0; 3])).unwrap();
    assert_eq!((report.replies, report.missing, report.rejected), (3, 0, 4));
    let r = drivers[0].stats().rejects;
    assert_eq!((r.wrong_length, r.unknown_id, r.unknown_motor), (1, 2, 1));
}

#[test]
fn bus_off_is_a_typed_error_and_nan_commands_send_nothing() {
    let plan = CanFaultPlan {
        bus_off: vec![(SimInstant::ZERO, SimInstant::from_nanos(1_000_000_000))],
        ..CanFaultPlan::default()
    };
    let (rig, mut drivers) = setup([plan, CanFaultPlan::default()]);
    let err = drivers[0].cycle(&hold([0.0; 3])).unwrap_err();
    assert!(matches!(err, MitError::Bus(CanError::BusOff { .. })), "{err}");

    let mut cmds = hold([0.0; 3]);
    cmds[2].q = f64::NAN;
    let frames_before = rig.lock().unwrap().buses()[1].stats().frames;
    let err = drivers[1].cycle(&cmds).unwrap_err();
    assert!(err.to_string().contains("ankle_1"), "{err}");
    assert_eq!(
        rig.lock().unwrap().buses()[1].stats().frames,
        frames_before,
        "nothing was sent"
    );
    assert!(matches!(
        drivers[1].cycle(&cmds[..2]),
        Err(MitError::CommandCount {
            expected: 3,
            actual: 2
        })
    ));
}

#[test]
fn steady_state_cycles_do_not_allocate() {
    let (rig, mut drivers) = setup(Default::default());
    for d in &mut drivers {
        d.enable_all().unwrap();
    }
    let cmds = hold([0.1, 0.2, 0.3]);
    for _ in 0..5 {
        tick(&rig, &mut drivers, &cmds);
    }
    let (_, stats) = count_allocations(|| {
        for _ in 0..50 {
            for d in &mut drivers {
                d.cycle(&cmds).unwrap();
            }
        }
    });
    assert!(stats.is_zero(), "{stats:?}");
}

#[test]
fn duplicate_motor_ids_and_bad_directions_are_refused() {
    let model = find("AK80-9").unwrap().clone();
    let j = |name: &str, id, direction| MitJointConfig {
        direction,
        ..MitJointConfig::new(name, id, &model)
    };
    let bus = VirtualCanBus::new("can0", 1_000_000);
    let rig = MitRig::new(vec![bus], Duration::from_micros(500)).shared();
    let err = MitBusDriver::new(
        MitRig::host_port(&rig, 0),
        vec![j("a", 1, 1.0), j("b", 1, 1.0)],
        REPLY_TIMEOUT,
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("motor ID 1 is also used by joint a"),
        "{err}"
    );
    let err = MitBusDriver::new(MitRig::host_port(&rig, 0), vec![j("a", 1, 0.5)], REPLY_TIMEOUT).unwrap_err();
    assert!(err.to_string().contains("direction = 0.5"), "{err}");
}
