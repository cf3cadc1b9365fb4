//! The servo side of a Feetech line: the servos hearing packets and answering in their turn, on
//! the protocol-agnostic simulated wire ([`crate::half_duplex::HalfDuplexWire`]), and a small rig
//! of servos turning inertias for tests, benches and `feetech emulate`.
//!
//! Timing: a servo starts its status packet Return Delay after the instruction ends; in a sync
//! read each listed servo starts after the previous one's packet has ended.

use std::collections::VecDeque;
use std::time::Duration;

use super::models::FeetechModel;
use super::packet::{self, Decoded};
use super::servo::{Reply, ReplySlot, StsConfig, StsServo};
use crate::half_duplex::{HalfDuplexWire, LineDevices, WireTiming};
use crate::plant::InertiaPlant;
use crate::serial::SerialSimWorld;
use crate::time::{SimInstant, SimWorld};

/// Counters of the servo side of a line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChainStats {
    /// Instruction packets decoded.
    pub packets: u64,
    /// Packets dropped for a bad checksum.
    pub checksum_errors: u64,
    /// Bytes skipped while hunting for a header.
    pub junk_bytes: u64,
    /// Status packets sent.
    pub replies: u64,
}

#[derive(Debug, Clone, Copy)]
struct Scheduled {
    start: SimInstant,
    from: usize,
    to: usize,
}

/// Largest instruction packet (LEN is one byte).
const MAX_PACKET: usize = 260;

/// The servos on one line, as they hear and answer it.
#[derive(Debug)]
pub struct FeetechChain {
    servos: Vec<StsServo>,
    timing: WireTiming,
    rx: Vec<u8>,
    answers: Vec<(usize, usize, Reply)>,
    scheduled: VecDeque<Scheduled>,
    reply_bytes: Vec<u8>,
    last_rx_at: SimInstant,
    stats: ChainStats,
}

impl FeetechChain {
    /// Servos on a line with `timing`.
    pub fn new(servos: Vec<StsServo>, timing: WireTiming) -> Self {
        let n = servos.len();
        Self {
            servos,
            timing,
            rx: Vec::with_capacity(4 * MAX_PACKET),
            answers: Vec::with_capacity(n),
            scheduled: VecDeque::with_capacity(n + 4),
            reply_bytes: Vec::with_capacity(n * 64 + 512),
            last_rx_at: SimInstant::ZERO,
            stats: ChainStats::default(),
        }
    }

    /// The servos.
    pub fn servos(&self) -> &[StsServo] {
        &self.servos
    }

    /// The servos, to inject faults or inspect.
    pub fn servos_mut(&mut self) -> &mut [StsServo] {
        &mut self.servos
    }

    /// Counters.
    pub fn stats(&self) -> ChainStats {
        self.stats
    }

    fn schedule(&mut self, now: SimInstant) {
        self.answers.sort_unstable_by_key(|&(order, _, _)| order);
        if self.scheduled.is_empty() {
            self.reply_bytes.clear();
        }
        let mut line_free = now;
        for &(_, index, reply) in &self.answers {
            let servo = &self.servos[index];
            let from = self.reply_bytes.len();
            self.reply_bytes.resize(from + reply.len + 6, 0);
            let n = packet::encode(
                reply.id,
                reply.error,
                servo.reply_params(&reply),
                &mut self.reply_bytes[from..],
            )
            .unwrap_or(0);
            self.reply_bytes.truncate(from + n);
            if reply.corrupt_checksum && n > 0 {
                self.reply_bytes[from + n - 1] ^= 0x5A;
            }
            let start = line_free + servo.return_delay() + reply.extra_delay;
            line_free = start + self.timing.bytes_time(n);
            self.scheduled.push_back(Scheduled {
                start,
                from,
                to: from + n,
            });
            self.stats.replies += 1;
        }
    }
}

impl LineDevices for FeetechChain {
    fn timing(&self) -> WireTiming {
        self.timing
    }

    fn receive(&mut self, bytes: &[u8], now: SimInstant) {
        // A line idle for a while ends any partial packet, as the firmware's timeout does.
        if now.saturating_since(self.last_rx_at) > self.timing.bytes_time(32).max(Duration::from_millis(2)) {
            self.stats.junk_bytes += self.rx.len() as u64;
            self.rx.clear();
        }
        self.last_rx_at = now;
        if self.rx.len() + bytes.len() > self.rx.capacity() {
            let keep = self.rx.len().min(1);
            self.stats.junk_bytes += (self.rx.len() - keep) as u64;
            self.rx.drain(..self.rx.len() - keep);
        }
        self.rx.extend_from_slice(bytes);
        loop {
            let used = match packet::decode(&self.rx) {
                Decoded::Packet {
                    id,
                    first,
                    params: (from, to),
                    used,
                } => {
                    self.stats.packets += 1;
                    self.answers.clear();
                    let baud = self.timing.baud;
                    for (index, servo) in self.servos.iter_mut().enumerate() {
                        if servo.baud() != Some(baud) {
                            continue;
                        }
                        if let Some(reply) = servo.handle(id, first, &self.rx[from..to]) {
                            let order = match reply.slot {
                                ReplySlot::First => 0,
                                ReplySlot::InList(k) => k,
                            };
                            self.answers.push((order, index, reply));
                        }
                    }
                    self.schedule(now);
                    used
                }
                Decoded::Incomplete { skip } => {
                    self.stats.junk_bytes += skip as u64;
                    self.rx.drain(..skip);
                    break;
                }
                Decoded::Invalid { checksum, skip, .. } => {
                    if checksum {
                        self.stats.checksum_errors += 1;
                    } else {
                        self.stats.junk_bytes += skip as u64;
                    }
                    skip
                }
            };
            self.rx.drain(..used);
        }
    }

    fn next_reply_at(&self) -> Option<SimInstant> {
        self.scheduled.iter().map(|s| s.start).min()
    }

    fn take_replies_due(&mut self, now: SimInstant, sink: &mut dyn FnMut(SimInstant, &[u8])) {
        while let Some(i) = (0..self.scheduled.len())
            .filter(|&i| self.scheduled[i].start <= now)
            .min_by_key(|&i| self.scheduled[i].start)
        {
            let s = self.scheduled.remove(i).expect("index in range");
            sink(s.start, &self.reply_bytes[s.from..s.to]);
        }
    }
}

/// A Feetech line in simulated time between a host's USB adapter and its servos.
pub type SimFeetechWire = HalfDuplexWire<FeetechChain>;

/// Emulated servos on one line, each turning an [`InertiaPlant`].
#[derive(Debug)]
pub struct FeetechRig {
    wire: SimFeetechWire,
    plants: Vec<InertiaPlant>,
    now: SimInstant,
    period: Duration,
    next_tick: SimInstant,
    busy: Duration,
}

impl FeetechRig {
    /// Servos `(id, model)` at `baud` with no return delay, each turning a small link (2 g·m²,
    /// light friction), firmware at 1 kHz.
    ///
    /// # Panics
    /// When `baud` is not a rate the servos have.
    pub fn bench(servos: &[(u8, &FeetechModel)], baud: u32) -> Self {
        let index = super::table::index_of_baud(baud).expect("a Feetech baud rate");
        let emulated = servos
            .iter()
            .map(|&(id, model)| {
                StsServo::new(
                    model,
                    StsConfig {
                        baud_index: index,
                        ..StsConfig::new(id, model)
                    },
                )
            })
            .collect();
        Self {
            wire: SimFeetechWire::new(FeetechChain::new(emulated, WireTiming::new(baud))),
            plants: servos
                .iter()
                .map(|_| InertiaPlant::new(2e-3, 0.05, 0.02, 0.0))
                .collect(),
            now: SimInstant::ZERO,
            period: Duration::from_millis(1),
            next_tick: SimInstant::ZERO,
            busy: Duration::ZERO,
        }
    }

    /// The wire and its servos.
    pub fn wire(&self) -> &SimFeetechWire {
        &self.wire
    }

    /// The servo at `index`, to inject faults.
    pub fn servo_mut(&mut self, index: usize) -> &mut StsServo {
        &mut self.wire.chain_mut().servos[index]
    }

    /// The servo at `index`.
    pub fn servo(&self, index: usize) -> &StsServo {
        &self.wire.chain().servos[index]
    }

    /// The plants.
    pub fn plants(&self) -> &[InertiaPlant] {
        &self.plants
    }

    /// CPU time spent inside the world, for benches that separate the host's share.
    pub fn busy(&self) -> Duration {
        self.busy
    }
}

impl SimWorld for FeetechRig {
    fn now(&self) -> SimInstant {
        self.now
    }

    fn step_until(&mut self, limit: SimInstant) -> SimInstant {
        let started = std::time::Instant::now();
        let next = self
            .wire
            .next_event(self.now)
            .map_or(limit, |t| t.min(limit))
            .min(self.next_tick);
        self.now = self.now.max(next);
        self.wire.advance(self.now);
        if self.now >= self.next_tick {
            let dt = self.period.as_secs_f64();
            for (servo, plant) in self.wire.chain_mut().servos.iter_mut().zip(&mut self.plants) {
                servo.tick(self.now, plant);
                plant.integrate(dt);
            }
            self.next_tick = self.next_tick + self.period;
        }
        self.busy += started.elapsed();
        self.now
    }
}

impl SerialSimWorld for FeetechRig {
    fn host_transmit(&mut self, _line: usize, bytes: &[u8]) {
        self.wire.host_transmit(self.now, bytes);
    }

    fn host_receive(&mut self, _line: usize, out: &mut Vec<u8>) {
        self.wire.host_receive(self.now, out);
    }
}
