//! Bench: Feetech STS3215 servos on one half-duplex line.
//!
//! For 4, 8 and 20 servos at 1 Mbit/s and 500 kbit/s, one control tick's traffic (one sync write
//! of goal positions, one sync read of the 15-byte state block, each servo answering in turn):
//! 1. wire time per cycle: the real driver against emulated servos (return delay 0) in lockstep
//!    simulated time, so the figure is the modelled line's bytes × 10 / baud;
//! 2. host CPU per cycle: the same driver on a replay transport that encodes each instruction and
//!    decodes pre-recorded status packets with the shared codec, p50/p99;
//! 3. the host's share of the wire time.
//!
//! Run: `cargo bench -p firmware-bridge --bench feetech_bus`

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use firmware_bridge::feetech::driver::{
    FeetechBusDriver, FeetechDriverOptions, FeetechJointConfig, LockstepFeetechPort,
};
use firmware_bridge::feetech::models::find;
use firmware_bridge::feetech::packet::{self, Feetech, inst};
use firmware_bridge::feetech::wire::FeetechRig;
use firmware_bridge::half_duplex::{LinkError, ServoCodec, ServoTransport, StatusDecode, StatusPacket};
use firmware_bridge::time::{SimInstant, SimWorld};
use test_support::stats::Summary;

const MODEL: &str = "STS3215";

fn joints(n: usize) -> Vec<FeetechJointConfig> {
    let m = find(MODEL).unwrap();
    (0..n)
        .map(|i| FeetechJointConfig::new(&format!("j{}", i + 1), i as u8 + 1, m))
        .collect()
}

fn goals(n: usize, k: usize) -> Vec<f64> {
    (0..n).map(|i| 0.3 * ((i + k) as f64 * 0.1).sin()).collect()
}

/// Passes through to the lockstep port, keeping a copy of each status packet (re-encoded).
struct Recorder {
    inner: LockstepFeetechPort<FeetechRig>,
    recorded: Vec<Vec<u8>>,
    recording: bool,
}

impl ServoTransport for Recorder {
    type Codec = Feetech;
    type Instant = SimInstant;
    fn now(&self) -> SimInstant {
        self.inner.now()
    }
    fn baud(&self) -> u32 {
        self.inner.baud()
    }
    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError> {
        self.inner.send(id, instruction, params)
    }
    fn recv_status(&mut self, deadline: SimInstant) -> Result<StatusPacket<'_>, LinkError> {
        let s = self.inner.recv_status(deadline)?;
        if self.recording {
            let mut buf = vec![0u8; s.params.len() + 6];
            let n = packet::encode(s.id, s.error, s.params, &mut buf).unwrap();
            buf.truncate(n);
            self.recorded.push(buf);
        }
        Ok(s)
    }
    fn recv_raw(&mut self, total: usize, deadline: SimInstant) -> Result<&[u8], LinkError> {
        self.inner.recv_raw(total, deadline)
    }
}

/// Simulated duration of one cycle, and the status packets the servos sent in it.
fn wire_floor(servos: usize, baud: u32) -> (Duration, Vec<Vec<u8>>) {
    let m = find(MODEL).unwrap();
    let list: Vec<_> = (0..servos).map(|i| (i as u8 + 1, m)).collect();
    let world = Arc::new(Mutex::new(FeetechRig::bench(&list, baud)));
    let recorder = Recorder {
        inner: LockstepFeetechPort::new(Arc::clone(&world), 0, baud),
        recorded: Vec::new(),
        recording: false,
    };
    let mut d = FeetechBusDriver::new(recorder, joints(servos), FeetechDriverOptions::default()).unwrap();
    d.configure().unwrap();
    d.enable().unwrap();
    d.cycle(&goals(servos, 0)).unwrap();
    let t0 = world.lock().unwrap().now();
    d.transport_mut().recording = true;
    let report = d.cycle(&goals(servos, 1)).unwrap();
    assert_eq!(report.fresh, servos);
    let took = world.lock().unwrap().now() - t0;
    (took, std::mem::take(&mut d.transport_mut().recorded))
}

/// Encodes instructions and decodes recorded status packets, with no wire and no servos.
struct Replay {
    packets: Vec<Vec<u8>>,
    next: usize,
    tx: Vec<u8>,
    scratch: Vec<u8>,
}

impl ServoTransport for Replay {
    type Codec = Feetech;
    type Instant = Instant;
    fn now(&self) -> Instant {
        Instant::now()
    }
    fn baud(&self) -> u32 {
        1_000_000
    }
    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError> {
        let n =
            Feetech::encode_instruction(id, instruction, params, &mut self.tx).ok_or(LinkError::Malformed)?;
        std::hint::black_box(&self.tx[..n]);
        if instruction == inst::SYNC_READ {
            self.next = 0;
        }
        Ok(())
    }
    fn recv_status(&mut self, _deadline: Instant) -> Result<StatusPacket<'_>, LinkError> {
        let bytes = self.packets.get(self.next).ok_or(LinkError::Timeout)?;
        self.next += 1;
        match Feetech::decode_status(bytes, &mut self.scratch) {
            StatusDecode::Status {
                id, error, params, ..
            } => Ok(StatusPacket {
                id,
                error,
                params: &self.scratch[params.0..params.1],
            }),
            _ => Err(LinkError::Malformed),
        }
    }
    fn recv_raw(&mut self, _total: usize, _deadline: Instant) -> Result<&[u8], LinkError> {
        Err(LinkError::Timeout)
    }
}

fn host_cpu(servos: usize, recorded: Vec<Vec<u8>>, quick: bool) -> Summary {
    let replay = Replay {
        packets: recorded,
        next: 0,
        tx: vec![0; 1024],
        scratch: vec![0; 1024],
    };
    let mut d = FeetechBusDriver::new(replay, joints(servos), FeetechDriverOptions::default()).unwrap();
    let q = goals(servos, 0);
    let n = if quick { 200 } else { 50_000 };
    let mut samples = Vec::with_capacity(n);
    for _ in 0..n {
        let t0 = Instant::now();
        let r = d.cycle(&q).unwrap();
        samples.push(t0.elapsed());
        assert_eq!(r.fresh, servos);
    }
    Summary::of(&mut samples[n / 10..]).expect("samples")
}

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    println!(
        "Feetech {MODEL}: one sync write (3 B/servo) + one sync read (21 B answered per servo) per tick"
    );
    println!(
        "{:>7} {:>9} {:>15} {:>12} {:>12} {:>12} {:>10}",
        "servos", "kbit/s", "wire µs/cycle", "max rate", "host p50 µs", "host p99 µs", "host/wire"
    );
    for baud in [1_000_000, 500_000] {
        for servos in [4, 8, 20] {
            let (wire, recorded) = wire_floor(servos, baud);
            let host = host_cpu(servos, recorded, quick);
            let wire_us = wire.as_secs_f64() * 1e6;
            println!(
                "{servos:>7} {:>9} {wire_us:>15.1} {:>9.0} Hz {:>12.2} {:>12.2} {:>9.2}%",
                baud / 1000,
                1e6 / wire_us,
                host.p50_us,
                host.p99_us,
                100.0 * host.p50_us / wire_us,
            );
        }
    }
}
