//! Bench: Dynamixel X-series servos on one half-duplex line.
//!
//! For 4, 8 and 20 servos at 1 and 4 Mbit/s, one control tick's traffic (one sync write of goal
//! position + goal current, one sync read of the 16-byte feedback block):
//! 1. wire-time floor: the real driver against emulated servos (Return Delay Time 0) in lockstep
//!    simulated time, so the figure is exactly bytes × 10 / baud on the modelled line;
//! 2. host CPU per cycle: the same driver on a replay transport that encodes each instruction and
//!    decodes pre-recorded status packets with the shared codec (what a serial transport does
//!    besides the system calls), p50/p99;
//! 3. host share of the wire time (target: under 5 %);
//! 4. the same with the state read by Fast Sync Read (0x8A): one status packet for all servos
//!    instead of one each — the wire time saved per cycle, and the host CPU of parsing it.
//!
//! Run: `cargo bench -p firmware-bridge --bench dxl_bus`

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use firmware_bridge::dxl::driver::{DxlBusDriver, DxlCommand, DxlDriverOptions, DxlJointConfig};
use firmware_bridge::dxl::models::find;
use firmware_bridge::dxl::packet::{self, Decoded};
use firmware_bridge::dxl::servo::{ServoConfig, XSeriesServo};
use firmware_bridge::dxl::transport::{Dynamixel2, LinkError, LockstepDxlPort, StatusPacket};
use firmware_bridge::dxl::wire::{DxlRig, WireTiming};
use firmware_bridge::half_duplex::ServoTransport;
use firmware_bridge::plant::InertiaPlant;
use firmware_bridge::time::SimWorld;
use test_support::stats::Summary;

const MODEL: &str = "XM430-W350";

fn joints(n: usize) -> Vec<DxlJointConfig> {
    (0..n)
        .map(|i| DxlJointConfig::new(&format!("j{}", i + 1), i as u8 + 1, MODEL))
        .collect()
}

fn commands(n: usize, k: usize) -> Vec<DxlCommand> {
    (0..n)
        .map(|i| DxlCommand {
            q: 0.3 * ((i + k) as f64 * 0.1).sin(),
            current: 0.8,
        })
        .collect()
}

/// Simulated duration of one cycle, and the status packets the servos sent in it (with `fast`,
/// the one fast-read packet).
fn wire_floor(servos: usize, baud: u32, fast: bool) -> (Duration, Vec<Vec<u8>>) {
    let model = find(MODEL).unwrap();
    let rig = DxlRig::new(
        (0..servos)
            .map(|i| XSeriesServo::new(model, ServoConfig::new(i as u8 + 1).on_line(baud, Duration::ZERO)))
            .collect(),
        (0..servos)
            .map(|_| InertiaPlant::new(2e-3, 0.05, 0.02, 0.0))
            .collect(),
        WireTiming::new(baud),
        Duration::from_micros(500),
    );
    let world = Arc::new(Mutex::new(rig));
    let recorder = Recorder {
        inner: LockstepDxlPort::new(Arc::clone(&world), 0, baud),
        recorded: Vec::new(),
        recording: false,
    };
    let options = DxlDriverOptions {
        expected_return_delay: Duration::ZERO,
        watchdog: None,
        fast_reads: fast,
        ..DxlDriverOptions::default()
    };
    let mut d = DxlBusDriver::new(recorder, joints(servos), options).unwrap();
    d.configure().unwrap();
    d.enable().unwrap();
    d.cycle(&commands(servos, 0)).unwrap();
    // The host sends the sync read as soon as the sync write is out; the cycle ends with the
    // last status packet.
    let t0 = world.lock().unwrap().now();
    let report = d.cycle(&commands(servos, 1)).unwrap();
    assert_eq!(report.fresh, servos);
    let took = world.lock().unwrap().now() - t0;
    // Record one cycle's status packets for the replay transport.
    d.transport_mut().recording = true;
    d.cycle(&commands(servos, 2)).unwrap();
    let recorded = std::mem::take(&mut d.transport_mut().recorded);
    (took, recorded)
}

/// Passes through to the lockstep port, keeping a copy of each status packet (re-encoded).
struct Recorder {
    inner: LockstepDxlPort<DxlRig>,
    recorded: Vec<Vec<u8>>,
    recording: bool,
}

impl ServoTransport for Recorder {
    type Codec = Dynamixel2;
    type Instant = firmware_bridge::time::SimInstant;
    fn now(&self) -> Self::Instant {
        self.inner.now()
    }
    fn baud(&self) -> u32 {
        self.inner.baud()
    }
    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError> {
        self.inner.send(id, instruction, params)
    }
    fn recv_status(&mut self, deadline: Self::Instant) -> Result<StatusPacket<'_>, LinkError> {
        let s = self.inner.recv_status(deadline)?;
        if self.recording {
            let mut buf = vec![0u8; 64 + 2 * s.params.len()];
            let n = packet::encode_status(s.id, s.error, s.params, &mut buf).unwrap();
            buf.truncate(n);
            self.recorded.push(buf);
        }
        Ok(s)
    }
    fn recv_raw(&mut self, total: usize, deadline: Self::Instant) -> Result<&[u8], LinkError> {
        let bytes = self.inner.recv_raw(total, deadline)?;
        if self.recording {
            self.recorded.push(bytes.to_vec());
        }
        Ok(bytes)
    }
}

/// Encodes instructions and decodes recorded status packets, with no wire and no servos.
struct Replay {
    packets: Vec<Vec<u8>>,
    next: usize,
    tx: Vec<u8>,
    scratch: Vec<u8>,
}

impl ServoTransport for Replay {
    type Codec = Dynamixel2;
    type Instant = Instant;
    fn now(&self) -> Instant {
        Instant::now()
    }
    fn baud(&self) -> u32 {
        1_000_000
    }
    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError> {
        let n = packet::encode_instruction(id, instruction, params, &mut self.tx)
            .map_err(|_| LinkError::Malformed)?;
        std::hint::black_box(&self.tx[..n]);
        if instruction == packet::inst::SYNC_READ || instruction == packet::inst::FAST_SYNC_READ {
            self.next = 0;
        }
        Ok(())
    }
    fn recv_raw(&mut self, _total: usize, _deadline: Instant) -> Result<&[u8], LinkError> {
        self.packets.first().map(Vec::as_slice).ok_or(LinkError::Timeout)
    }
    fn recv_status(&mut self, _deadline: Instant) -> Result<StatusPacket<'_>, LinkError> {
        let bytes = self.packets.get(self.next).ok_or(LinkError::Timeout)?;
        self.next += 1;
        match packet::decode(bytes, &mut self.scratch) {
            Decoded::Packet(p, _) => Ok(StatusPacket {
                id: p.id,
                error: p.error.unwrap_or(0),
                params: p.params,
            }),
            _ => Err(LinkError::Malformed),
        }
    }
}

fn host_cpu(servos: usize, recorded: Vec<Vec<u8>>, quick: bool, fast: bool) -> Summary {
    let replay = Replay {
        packets: recorded,
        next: 0,
        tx: vec![0; 4096],
        scratch: vec![0; 4096],
    };
    let options = DxlDriverOptions {
        fast_reads: fast,
        ..DxlDriverOptions::default()
    };
    let mut d = DxlBusDriver::new(replay, joints(servos), options).unwrap();
    let cmds = commands(servos, 0);
    let n = if quick { 200 } else { 50_000 };
    let mut samples = Vec::with_capacity(n);
    for _ in 0..n {
        let t0 = Instant::now();
        let r = d.cycle(&cmds).unwrap();
        samples.push(t0.elapsed());
        assert_eq!(r.fresh, servos);
    }
    Summary::of(&mut samples[n / 10..]).expect("samples")
}

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    println!(
        "Dynamixel Protocol 2.0, {MODEL}: one sync write (6 B/servo) + one sync read (16 B/servo) per tick"
    );
    println!(
        "{:>7} {:>9} {:>6} {:>15} {:>12} {:>12} {:>12} {:>10}",
        "servos", "Mbit/s", "read", "wire µs/cycle", "max rate", "host p50 µs", "host p99 µs", "host/wire"
    );
    for baud in [1_000_000, 4_000_000] {
        for servos in [4, 8, 20] {
            let mut sync_us = 0.0;
            for fast in [false, true] {
                let (wire, recorded) = wire_floor(servos, baud, fast);
                let host = host_cpu(servos, recorded, quick, fast);
                let wire_us = wire.as_secs_f64() * 1e6;
                let share = 100.0 * host.p50_us / wire_us;
                let saved = if fast {
                    format!("  ({:.0} % less wire time)", 100.0 * (1.0 - wire_us / sync_us))
                } else {
                    sync_us = wire_us;
                    String::new()
                };
                println!(
                    "{servos:>7} {:>9} {:>6} {wire_us:>15.1} {:>9.0} Hz {:>12.2} {:>12.2} {share:>9.2}%{saved}",
                    baud / 1_000_000,
                    if fast { "fast" } else { "sync" },
                    1e6 / wire_us,
                    host.p50_us,
                    host.p99_us,
                );
            }
        }
    }
}
