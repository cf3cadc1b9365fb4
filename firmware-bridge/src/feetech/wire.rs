//! The servo side of a Feetech line: the servos hearing packets and answering in their turn, on
//! the protocol-agnostic simulated wire ([`crate::half_duplex::HalfDuplexWire`]), and a small rig
//! of servos turning inertias for tests, benches and `feetech emulate`
//! ([`crate::half_duplex::LineRig`]).
//!
//! Timing: a servo starts its status packet Return Delay after the instruction ends; in a sync
//! read each listed servo starts after the previous one's packet has ended.

use std::time::Duration;

use super::models::FeetechModel;
use super::packet::{self, Decoded};
use super::servo::{Reply, ReplySlot, StsConfig, StsServo};
use crate::half_duplex::{HalfDuplexWire, LineDevices, LineRig, ReplySchedule, ServoLine, WireTiming};
use crate::plant::InertiaPlant;
use crate::time::SimInstant;

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

/// Largest instruction packet (LEN is one byte).
const MAX_PACKET: usize = 260;

/// The servos on one line, as they hear and answer it.
#[derive(Debug)]
pub struct FeetechChain {
    servos: Vec<StsServo>,
    timing: WireTiming,
    rx: Vec<u8>,
    answers: Vec<(usize, usize, Reply)>,
    replies: ReplySchedule,
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
            replies: ReplySchedule::with_capacity(n + 4, n * 64 + 512),
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
        let mut line_free = now;
        for &(_, index, reply) in &self.answers {
            let servo = &self.servos[index];
            let bytes = self.replies.bytes_mut();
            let from = bytes.len();
            bytes.resize(from + reply.len + 6, 0);
            let n = packet::encode(
                reply.id,
                reply.error,
                servo.reply_params(&reply),
                &mut bytes[from..],
            )
            .unwrap_or(0);
            bytes.truncate(from + n);
            if reply.corrupt_checksum && n > 0 {
                bytes[from + n - 1] ^= 0x5A;
            }
            let start = line_free + servo.return_delay() + reply.extra_delay;
            line_free = start + self.timing.bytes_time(n);
            self.replies.push(start, from);
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
        self.replies.next_at()
    }

    fn take_replies_due(&mut self, now: SimInstant, sink: &mut dyn FnMut(SimInstant, &[u8])) {
        self.replies.take_due(now, sink);
    }
}

impl ServoLine for FeetechChain {
    fn tick_servos(&mut self, now: SimInstant, plants: &mut [InertiaPlant]) {
        for (servo, plant) in self.servos.iter_mut().zip(plants) {
            servo.tick(now, plant);
        }
    }
}

/// A Feetech line in simulated time between a host's USB adapter and its servos.
pub type SimFeetechWire = HalfDuplexWire<FeetechChain>;

/// Emulated STS servos on one line, each turning an [`InertiaPlant`].
pub type FeetechRig = LineRig<FeetechChain>;

impl LineRig<FeetechChain> {
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
        Self::with_devices(
            FeetechChain::new(emulated, WireTiming::new(baud)),
            servos
                .iter()
                .map(|_| InertiaPlant::new(2e-3, 0.05, 0.02, 0.0))
                .collect(),
            Duration::from_millis(1),
        )
    }

    /// The servo at `index`, to inject faults.
    pub fn servo_mut(&mut self, index: usize) -> &mut StsServo {
        &mut self.wire_mut().chain_mut().servos[index]
    }

    /// The servo at `index`.
    pub fn servo(&self, index: usize) -> &StsServo {
        &self.wire().chain().servos[index]
    }
}
