//! Bench: MIT-mode motors on CAN.
//!
//! 1. Bus load: 6, 12 and 20 motors spread over 1, 2 and 4 buses at 1 Mbit/s, one command and one
//!    reply per motor per tick, measured on the bit-exact wire model (stuff bits included) by
//!    running the real driver against emulated motors; shown at 50 Hz and 500 Hz.
//! 2. Host CPU per cycle: encode every command and decode every reply for one bus (driver
//!    bookkeeping included, transport excluded), p50/p99 over many cycles.
//! 3. Robstride's factory protocol beside MIT mode on one bus, N = 4, 8, 20: wire time per cycle
//!    (29-bit identifiers cost 20 bits more per frame, before stuffing) and host CPU per cycle.
//!
//! Run: `cargo bench -p firmware-bridge --bench mit_bus`

use std::time::{Duration, Instant};

use firmware_bridge::can::virtual_bus::VirtualCanBus;
use firmware_bridge::can::{CanBus, CanError, CanFrame};
use firmware_bridge::mit::codec::{MitReply, reply_frame};
use firmware_bridge::mit::driver::{JointCommand, MitBusDriver, MitJointConfig};
use firmware_bridge::mit::firmware::MitFirmwareConfig;
use firmware_bridge::mit::models::{MotorModel, find};
use firmware_bridge::mit::rig::MitRig;
use firmware_bridge::plant::InertiaPlant;
use test_support::stats::Summary;

const BITRATE: u32 = 1_000_000;

fn joint(i: usize, model: &MotorModel) -> MitJointConfig {
    let id = (i + 1) as u8;
    MitJointConfig::new(&format!("j{id}"), id, model)
}

fn commands(n: usize, k: usize) -> Vec<JointCommand> {
    (0..n)
        .map(|i| JointCommand {
            q: 0.3 * ((i + k) as f64 * 0.1).sin(),
            qd: 0.1,
            kp: 40.0,
            kd: 1.0,
            tau: 0.5,
        })
        .collect()
}

/// Bits per cycle on the busiest bus, from the wire model's counters over real driver cycles.
fn busiest_bus_bits(model: &str, motors: usize, buses: usize) -> u64 {
    let model = find(model).unwrap();
    let wires: Vec<VirtualCanBus> = (0..buses)
        .map(|b| VirtualCanBus::new(&format!("can{b}"), BITRATE))
        .collect();
    let mut rig = MitRig::new(wires.clone(), Duration::from_micros(500));
    let mut per_bus: Vec<Vec<MitJointConfig>> = vec![Vec::new(); buses];
    for i in 0..motors {
        let b = i % buses;
        let j = joint(per_bus[b].len(), model);
        rig.add_motor(
            b,
            MitFirmwareConfig::new(j.motor_id, model),
            InertiaPlant::new(0.01, 0.05, 0.0, 0.0),
        );
        per_bus[b].push(j);
    }
    let rig = rig.shared();
    let mut drivers: Vec<_> = per_bus
        .into_iter()
        .enumerate()
        .map(|(b, js)| MitBusDriver::new(MitRig::host_port(&rig, b), js, Duration::from_millis(5)).unwrap())
        .collect();
    const CYCLES: u64 = 20;
    for k in 0..CYCLES as usize {
        for d in &mut drivers {
            let n = d.joints().len();
            d.cycle(&commands(n, k)).unwrap();
        }
    }
    wires.iter().map(|w| w.stats().bits / CYCLES).max().unwrap_or(0)
}

/// A transport that swallows commands and hands back pre-packed replies: isolates host CPU.
struct ReplayBus {
    replies: Vec<CanFrame>,
    next: usize,
    sent: usize,
}

impl CanBus for ReplayBus {
    type Instant = Instant;
    fn now(&self) -> Instant {
        Instant::now()
    }
    fn send(&mut self, frame: &CanFrame) -> Result<(), CanError> {
        // A cycle's first command: its replies are handed back from the start.
        if self.sent.is_multiple_of(self.replies.len()) {
            self.next = 0;
        }
        self.sent += 1;
        std::hint::black_box(frame);
        Ok(())
    }
    fn recv_until(&mut self, _deadline: Instant) -> Result<Option<CanFrame>, CanError> {
        let f = self.replies.get(self.next).copied();
        self.next += 1;
        Ok(f)
    }
}

fn host_cpu(model: &str, motors: usize, quick: bool) -> Summary {
    let model = find(model).unwrap();
    let joints: Vec<_> = (0..motors).map(|i| joint(i, model)).collect();
    let replies = joints
        .iter()
        .map(|j| {
            reply_frame(
                model,
                j.reply_id,
                &MitReply {
                    motor_id: j.motor_id,
                    p: 0.1,
                    v: 0.2,
                    t: 0.3,
                    ..MitReply::default()
                },
            )
        })
        .collect();
    let bus = ReplayBus {
        replies,
        next: 0,
        sent: 0,
    };
    let mut driver = MitBusDriver::new(bus, joints, Duration::from_millis(1)).unwrap();
    let cmds = commands(motors, 0);
    let n = if quick { 200 } else { 50_000 };
    let mut samples = Vec::with_capacity(n);
    for _ in 0..n {
        let t0 = Instant::now();
        let r = driver.cycle(&cmds).unwrap();
        samples.push(t0.elapsed());
        assert_eq!(r.replies, motors);
    }
    Summary::of(&mut samples[n / 10..]).expect("samples")
}

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    println!(
        "MIT-mode CAN at {} Mbit/s: one command + one reply per motor per tick (busiest bus)",
        BITRATE / 1_000_000
    );
    println!(
        "{:>7} {:>6} {:>12} {:>14} {:>12} {:>12}",
        "motors", "buses", "bits/cycle", "wire µs/cycle", "load @50Hz", "load @500Hz"
    );
    for motors in [6, 12, 20] {
        for buses in [1, 2, 4] {
            let bits = busiest_bus_bits("AK80-9", motors, buses);
            let wire_us = bits as f64 * 1e6 / f64::from(BITRATE);
            let load = |hz: f64| 100.0 * bits as f64 * hz / f64::from(BITRATE);
            let over = if load(500.0) > 100.0 {
                "  (500 Hz does not fit)"
            } else {
                ""
            };
            println!(
                "{motors:>7} {buses:>6} {bits:>12} {wire_us:>14.1} {:>11.1}% {:>11.1}%{over}",
                load(50.0),
                load(500.0)
            );
        }
    }
    println!();
    println!("host CPU per cycle (encode all commands + decode all replies, one bus):");
    for motors in [6, 12, 20] {
        let s = host_cpu("AK80-9", motors, quick);
        println!("  {motors:>2} motors: {s}");
    }
    println!();
    println!("Robstride (factory protocol, 29-bit IDs) vs MIT mode, one bus at 1 Mbit/s:");
    println!(
        "{:>7} {:>22} {:>22}   host CPU per cycle (Robstride)",
        "motors", "wire µs/cycle MIT", "wire µs/cycle RS"
    );
    for motors in [4, 8, 20] {
        let us = |model| busiest_bus_bits(model, motors, 1) as f64 * 1e6 / f64::from(BITRATE);
        let s = host_cpu("RS03", motors, quick);
        println!("{motors:>7} {:>22.1} {:>22.1}   {s}", us("AK80-9"), us("RS03"));
    }
}
