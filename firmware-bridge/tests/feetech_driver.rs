//! The Feetech host driver against emulated STS servos on a simulated line, in lockstep.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use firmware_bridge::feetech::driver::{
    FeetechBusDriver, FeetechDriverOptions, FeetechError, FeetechJointConfig, LockstepFeetechPort, gains_for,
    scan,
};
use firmware_bridge::feetech::models::find;
use firmware_bridge::feetech::packet::error;
use firmware_bridge::feetech::wire::FeetechRig;
use firmware_bridge::half_duplex::{LinkError, ReplyFault, ServoTransport, StatusPacket};
use firmware_bridge::time::SimWorld;
use test_support::alloc::{CountingAllocator, count_allocations};

#[global_allocator]
static ALLOC: CountingAllocator = CountingAllocator;

const BAUD: u32 = 1_000_000;
const TICK: Duration = Duration::from_millis(20);

type Driver = FeetechBusDriver<LockstepFeetechPort<FeetechRig>>;

fn setup(n: u8) -> (Arc<Mutex<FeetechRig>>, Driver) {
    let m = find("STS3215").unwrap();
    let servos: Vec<_> = (1..=n).map(|id| (id, m)).collect();
    let rig = Arc::new(Mutex::new(FeetechRig::bench(&servos, BAUD)));
    let joints = (1..=n)
        .map(|id| FeetechJointConfig {
            direction: if id % 2 == 0 { -1.0 } else { 1.0 },
            ..FeetechJointConfig::new(&format!("j{id}"), id, m)
        })
        .collect();
    let port = LockstepFeetechPort::new(Arc::clone(&rig), 0, BAUD);
    let driver = FeetechBusDriver::new(port, joints, FeetechDriverOptions::default()).unwrap();
    (rig, driver)
}

/// A 50 Hz tick: goals and state, then the rest of the period.
fn tick(d: &mut Driver, q: &[f64]) -> usize {
    let end = d.transport_mut().now() + TICK;
    let report = d.cycle(q).unwrap();
    let world = Arc::clone(d.transport_mut().shared_world());
    let mut w = world.lock().unwrap();
    while w.now() < end {
        w.step_until(end);
    }
    report.stale
}

/// A line on which every answer to a read of servo `garbled` arrives with a bad checksum (its
/// pings come through) — of every read, or only of reads from `only_from` on (the state block).
struct GarbledReads {
    inner: LockstepFeetechPort<FeetechRig>,
    garbled: u8,
    only_from: Option<u8>,
    reading_it: bool,
}

impl ServoTransport for GarbledReads {
    type Codec = <LockstepFeetechPort<FeetechRig> as ServoTransport>::Codec;
    type Instant = <LockstepFeetechPort<FeetechRig> as ServoTransport>::Instant;

    fn now(&self) -> Self::Instant {
        self.inner.now()
    }

    fn baud(&self) -> u32 {
        self.inner.baud()
    }

    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError> {
        self.reading_it = id == self.garbled
            && instruction == firmware_bridge::feetech::packet::inst::READ
            && self
                .only_from
                .is_none_or(|from| params.first().is_some_and(|&a| a >= from));
        self.inner.send(id, instruction, params)
    }

    fn recv_status(&mut self, deadline: Self::Instant) -> Result<StatusPacket<'_>, LinkError> {
        if self.reading_it {
            self.inner.recv_status(deadline)?;
            return Err(LinkError::Crc);
        }
        self.inner.recv_status(deadline)
    }

    fn recv_raw(&mut self, total: usize, deadline: Self::Instant) -> Result<&[u8], LinkError> {
        self.inner.recv_raw(total, deadline)
    }
}

#[test]
fn a_scan_goes_on_past_a_servo_whose_reads_come_back_garbled() {
    let (rig, _) = setup(3);
    let port = GarbledReads {
        inner: LockstepFeetechPort::new(Arc::clone(&rig), 0, BAUD),
        garbled: 2,
        only_from: None,
        reading_it: false,
    };
    // Servo 2 answers pings but not one read: it is not listed (its model is unknown), and
    // servo 3 after it is.
    let hits = scan(port, 1..=3, Duration::from_millis(5)).unwrap();
    let ids: Vec<u8> = hits.iter().map(|h| h.id).collect();
    assert_eq!(ids, [1, 3], "{hits:?}");
    // Its model read comes through, its state read does not: listed, its readings unknown (it
    // was listed at 0 ticks and 0 °C).
    let port = GarbledReads {
        inner: LockstepFeetechPort::new(Arc::clone(&rig), 0, BAUD),
        garbled: 2,
        only_from: Some(firmware_bridge::feetech::table::addr::PRESENT_POSITION),
        reading_it: false,
    };
    let hits = scan(port, 1..=3, Duration::from_millis(5)).unwrap();
    let two = hits.iter().find(|h| h.id == 2).expect("servo 2 is listed");
    assert_eq!(
        (two.position, two.temperature, two.status),
        (None, None, None),
        "{two:?}"
    );
    let one = &hits[0];
    assert!(
        one.position.is_some() && one.temperature.is_some_and(|t| t > 0),
        "{one:?}"
    );
}

#[test]
fn servos_follow_joint_goals_through_direction_and_report_their_state() {
    let (rig, mut d) = setup(4);
    d.configure().unwrap();
    d.enable().unwrap();
    let goals = [0.4, -0.3, 0.2, 0.6];
    for _ in 0..60 {
        assert_eq!(tick(&mut d, &goals), 0);
    }
    for (fb, want) in d.feedback().iter().zip(goals) {
        assert!((fb.q - want).abs() < 0.02, "{} want {want}", fb.q);
        assert!((fb.voltage - 7.4).abs() < 0.05 && fb.status == 0, "{fb:?}");
    }
    // Joint 2 runs against the servo's direction: its shaft turned the other way.
    let shaft = rig.lock().unwrap().plants()[1].q;
    assert!((shaft - 0.3).abs() < 0.03, "{shaft}");
    // A stiffer loop: P and D from the policy's gains, written in one sync write.
    let m = find("STS3215").unwrap();
    let g = gains_for(40.0, 1.0, m);
    d.write_gains(&[g; 4]).unwrap();
    tick(&mut d, &goals);
    assert_eq!(rig.lock().unwrap().servo(0).register(21), g[0]);
    // Steady cycles allocate nothing.
    let (_, stats) = count_allocations(|| {
        for _ in 0..20 {
            d.cycle(&goals).unwrap();
        }
    });
    assert!(stats.is_zero(), "{stats:?}");
    d.disable().unwrap();
    tick(&mut d, &goals);
    assert!(!rig.lock().unwrap().servo(2).torque_enabled());
}

#[test]
fn silent_corrupt_and_faulted_servos_mark_only_their_joint() {
    let (rig, mut d) = setup(3);
    d.configure().unwrap();
    d.enable().unwrap();
    tick(&mut d, &[0.0; 3]);
    rig.lock()
        .unwrap()
        .servo_mut(1)
        .inject(ReplyFault::Silent, Some(2));
    assert_eq!(tick(&mut d, &[0.0; 3]), 1);
    assert!(d.feedback()[1].is_stale() && !d.feedback()[0].is_stale() && !d.feedback()[2].is_stale());
    assert_eq!(tick(&mut d, &[0.0; 3]), 1);
    assert_eq!(d.feedback()[1].missed_cycles, 2);
    assert_eq!(tick(&mut d, &[0.0; 3]), 0, "back after its count");
    // A bad checksum: dropped, counted, the joint stale for that cycle.
    rig.lock()
        .unwrap()
        .servo_mut(2)
        .inject(ReplyFault::CorruptCrc, Some(1));
    let r = d.cycle(&[0.0; 3]).unwrap();
    assert_eq!((r.stale, r.rejected), (1, 1));
    // Another ID in a servo's place.
    rig.lock()
        .unwrap()
        .servo_mut(0)
        .inject(ReplyFault::WrongId(9), Some(1));
    let r = d.cycle(&[0.0; 3]).unwrap();
    assert_eq!((r.stale, r.rejected), (1, 1));
    // Overheat: the state stays fresh, the fault comes in the status byte.
    rig.lock().unwrap().servo_mut(0).raise_error(error::OVERHEAT);
    tick(&mut d, &[0.0; 3]);
    assert_eq!(d.feedback()[0].status & error::OVERHEAT, error::OVERHEAT);
    assert!(!d.feedback()[0].is_stale());
    // A vanished servo: stale every cycle, the line still serves the others.
    rig.lock().unwrap().servo_mut(2).vanish();
    for _ in 0..3 {
        assert_eq!(tick(&mut d, &[0.0; 3]), 1);
    }
    assert!(d.feedback()[2].missed_cycles >= 3);
    // NaN goals send nothing and say which joint.
    let e = d.write_goals(&[0.0, f64::NAN, 0.0]).unwrap_err();
    assert!(
        matches!(e, FeetechError::NotFinite { ref joint, .. } if joint == "j2"),
        "{e}"
    );
}

#[test]
fn set_up_checks_every_servos_identity_before_writing() {
    let (rig, _) = setup(2);
    let m = find("STS3215").unwrap();
    let port = LockstepFeetechPort::new(Arc::clone(&rig), 0, BAUD);
    let joints = vec![
        FeetechJointConfig::new("a", 1, m),
        FeetechJointConfig::new("b", 2, m),
        FeetechJointConfig::new("c", 7, m),
    ];
    let mut d = FeetechBusDriver::new(port, joints, FeetechDriverOptions::default()).unwrap();
    let e = d.configure().unwrap_err();
    assert!(matches!(e, FeetechError::NoReply { id: 7, .. }), "{e}");
    // Another model number in the table: refused by name.
    let mut other = m.clone();
    other.model_number = 1234;
    other.name = "STS9999".into();
    let port = LockstepFeetechPort::new(Arc::clone(&rig), 0, BAUD);
    let mut d = FeetechBusDriver::new(
        port,
        vec![FeetechJointConfig::new("a", 1, &other)],
        FeetechDriverOptions::default(),
    )
    .unwrap();
    let e = d.configure().unwrap_err().to_string();
    assert!(e.contains("servo 1 is model 777") && e.contains("STS9999"), "{e}");
    // Duplicate IDs never reach the line.
    let port = LockstepFeetechPort::new(rig, 0, BAUD);
    let e = FeetechBusDriver::new(
        port,
        vec![
            FeetechJointConfig::new("a", 1, m),
            FeetechJointConfig::new("b", 1, m),
        ],
        FeetechDriverOptions::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("also joint a"), "{e}");
}
