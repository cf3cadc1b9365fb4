//! The servo side of a half-duplex Dynamixel line: emulated servos sharing a wire, the wire's
//! timing in simulated time, and a small rig of servos turning inertias. [`crate::serial`] serves
//! any such world on a pseudo-terminal.
//!
//! Timing follows the line: an instruction takes `bytes × 10 / baud` to arrive; a servo starts
//! its status packet Return Delay Time after the instruction ends; in a sync/bulk read each
//! servo starts after the previous servo's status packet has ended; the host sees a status packet
//! when its last byte arrived plus the USB adapter's latency.

use std::time::Duration;

use super::models::DxlModel;
use super::packet::{self, Decoded, PacketError, inst};
use super::servo::{Reply, ReplySlot, ServoConfig, XSeriesServo};
use crate::half_duplex::{HalfDuplexWire, LineDevices, LineRig, ReplySchedule, ServoLine};
use crate::plant::InertiaPlant;
use crate::time::SimInstant;

/// Baud rate of an X-series Baud Rate code (address 8).
pub const fn baud_of_code(code: u8) -> Option<u32> {
    match code {
        0 => Some(9_600),
        1 => Some(57_600),
        2 => Some(115_200),
        3 => Some(1_000_000),
        4 => Some(2_000_000),
        5 => Some(3_000_000),
        6 => Some(4_000_000),
        7 => Some(4_500_000),
        _ => None,
    }
}

/// The Baud Rate code of a baud rate, if the servos support it.
pub fn code_of_baud(baud: u32) -> Option<u8> {
    (0..=7).find(|&c| baud_of_code(c) == Some(baud))
}

pub use crate::half_duplex::{ADAPTER_BUFFER_BYTES, WireTiming};

/// Counters of the servo side of a line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ChainStats {
    /// Complete instruction packets decoded.
    pub packets: u64,
    /// Packets dropped for a CRC mismatch.
    pub crc_errors: u64,
    /// Other malformed packets dropped.
    pub malformed: u64,
    /// Bytes skipped while hunting for a header.
    pub junk_bytes: u64,
    /// Status packets sent.
    pub replies: u64,
}

/// The servos on one line, as they hear and answer it.
#[derive(Debug)]
pub struct ServoChain {
    servos: Vec<XSeriesServo>,
    timing: WireTiming,
    rx: Vec<u8>,
    scratch: Vec<u8>,
    answers: Vec<(usize, usize, Reply)>,
    /// Where each servo's segment of a fast read's packet starts (reused).
    fast_offsets: Vec<usize>,
    replies: ReplySchedule,
    last_rx_at: SimInstant,
    stats: ChainStats,
}

/// Largest instruction the servos accept (a bulk write to many servos).
const MAX_PACKET: usize = 4096;

impl ServoChain {
    /// Servos on a line with `timing`.
    pub fn new(servos: Vec<XSeriesServo>, timing: WireTiming) -> Self {
        let n = servos.len();
        Self {
            servos,
            timing,
            rx: Vec::with_capacity(2 * MAX_PACKET),
            scratch: vec![0; MAX_PACKET],
            answers: Vec::with_capacity(n),
            fast_offsets: Vec::with_capacity(256),
            replies: ReplySchedule::with_capacity(n + 4, n * 512),
            last_rx_at: SimInstant::ZERO,
            stats: ChainStats::default(),
        }
    }

    /// The servos, in the order given.
    pub fn servos(&self) -> &[XSeriesServo] {
        &self.servos
    }

    /// The servos, to inject faults or inspect.
    pub fn servos_mut(&mut self) -> &mut [XSeriesServo] {
        &mut self.servos
    }

    /// Line timing.
    pub fn timing(&self) -> WireTiming {
        self.timing
    }

    /// Counters.
    pub fn stats(&self) -> ChainStats {
        self.stats
    }

    /// Bytes whose last bit arrived at `now`. Complete packets are executed at once.
    pub fn receive(&mut self, bytes: &[u8], now: SimInstant) {
        // Like the firmware's packet timeout: a line idle for a while ends any partial packet.
        let idle = now.saturating_since(self.last_rx_at);
        if idle > self.timing.bytes_time(64).max(Duration::from_millis(2)) {
            self.stats.junk_bytes += self.rx.len() as u64;
            self.rx.clear();
        }
        self.last_rx_at = now;
        if self.rx.len() + bytes.len() > self.rx.capacity() {
            // A flood without headers: keep only what could still start a packet.
            let keep = self.rx.len().min(3);
            self.stats.junk_bytes += (self.rx.len() - keep) as u64;
            self.rx.drain(..self.rx.len() - keep);
        }
        self.rx.extend_from_slice(bytes);
        loop {
            let used = match packet::decode(&self.rx, &mut self.scratch) {
                Decoded::Packet(p, used) => {
                    self.stats.packets += 1;
                    let junk = used - packet_len_hint(&self.rx[..used]);
                    self.stats.junk_bytes += junk as u64;
                    let packet = packet::Packet { ..p };
                    let fast = fast_read_layout(&packet, &mut self.fast_offsets);
                    let (servos, answers) = (&mut self.servos, &mut self.answers);
                    answers.clear();
                    for (index, servo) in servos.iter_mut().enumerate() {
                        if baud_of_code(servo.baud_code()) != Some(self.timing.baud) {
                            continue;
                        }
                        if let Some(reply) = servo.handle(&packet, now) {
                            let order = match reply.slot {
                                ReplySlot::First => 0,
                                ReplySlot::InList(k) | ReplySlot::Fast(k) => k,
                                ReplySlot::ById => usize::from(reply.id),
                            };
                            answers.push((order, index, reply));
                        }
                    }
                    match fast {
                        Some(len_field) => self.schedule_fast_answers(now, len_field),
                        None => self.schedule_answers(now),
                    }
                    used
                }
                Decoded::Incomplete { skip } => {
                    self.stats.junk_bytes += skip as u64;
                    self.rx.drain(..skip);
                    break;
                }
                Decoded::Invalid(error, id, skip) => {
                    match error {
                        PacketError::Crc { .. } => {
                            self.stats.crc_errors += 1;
                            self.answers.clear();
                            for (index, servo) in self.servos.iter_mut().enumerate() {
                                if let Some(reply) = id.and_then(|id| servo.handle_crc_error(id, now)) {
                                    self.answers.push((0, index, reply));
                                }
                            }
                            self.schedule_answers(now);
                        }
                        _ => self.stats.malformed += 1,
                    }
                    skip
                }
            };
            self.rx.drain(..used);
        }
    }

    fn schedule_answers(&mut self, now: SimInstant) {
        self.answers.sort_unstable_by_key(|&(order, _, _)| order);
        let mut line_free = now;
        for &(_, index, reply) in &self.answers {
            let servo = &self.servos[index];
            let bytes = self.replies.bytes_mut();
            let from = bytes.len();
            bytes.resize(from + 16 + 2 * reply.len, 0);
            let n = packet::encode_status(
                reply.id,
                reply.error,
                servo.reply_params(&reply),
                &mut bytes[from..],
            )
            .expect("a status packet fits twice its parameters plus the header");
            bytes.truncate(from + n);
            if reply.corrupt_crc {
                bytes[from + n - 1] ^= 0x5A;
            }
            let start = line_free + servo.return_delay() + reply.extra_delay;
            line_free = start + self.timing.bytes_time(n);
            self.replies.push(start, from);
            self.stats.replies += 1;
        }
    }

    /// A fast read's answers as its one status packet: the first servo listed sends the header
    /// (ID 0xFE, LEN for every listed servo, INST 0x55) and its segment; each next servo its
    /// segment — error, ID, data, and the CRC of all bytes on the wire so far — in the time slot
    /// the list gives it, whether or not the servos before it answered (a silent one leaves a
    /// gap and a short packet). Not byte-stuffed: no servo knows the whole packet.
    fn schedule_fast_answers(&mut self, now: SimInstant, len_field: usize) {
        self.answers.sort_unstable_by_key(|&(order, _, _)| order);
        let first_delay = self
            .answers
            .first()
            .map_or(Duration::ZERO, |&(_, index, _)| self.servos[index].return_delay());
        let t0 = now + first_delay;
        let mut line_free = t0;
        let mut crc = 0u16;
        for &(k, index, reply) in &self.answers {
            let servo = &self.servos[index];
            let bytes = self.replies.bytes_mut();
            let from = bytes.len();
            if k == 0 {
                let len = u16::try_from(len_field).unwrap_or(u16::MAX);
                bytes.extend_from_slice(&packet::HEADER);
                bytes.push(packet::BROADCAST_ID);
                bytes.extend_from_slice(&len.to_le_bytes());
                bytes.push(packet::STATUS);
            }
            bytes.push(reply.error);
            bytes.push(reply.id);
            bytes.extend_from_slice(servo.reply_params(&reply));
            crc = packet::crc16(crc, &bytes[from..]);
            let mut sent = crc;
            if reply.corrupt_crc {
                sent ^= 0x5A5A;
            }
            bytes.extend_from_slice(&sent.to_le_bytes());
            crc = packet::crc16(crc, &sent.to_le_bytes());
            let n = bytes.len() - from;
            let offsets = &self.fast_offsets;
            let slot = t0 + self.timing.bytes_time(offsets[k.min(offsets.len() - 1)]);
            let start = line_free.max(slot) + reply.extra_delay;
            line_free = start + self.timing.bytes_time(n);
            self.replies.push(start, from);
            self.stats.replies += 1;
        }
    }
}

/// The layout of the answer to a fast sync or bulk read: where each listed servo's segment
/// starts (bytes from the packet's start; the first after the 8-byte prefix) into `offsets`, and
/// the LEN field the packet carries; `None` for any other packet.
fn fast_read_layout(p: &packet::Packet<'_>, offsets: &mut Vec<usize>) -> Option<usize> {
    offsets.clear();
    let mut at = packet::FAST_STATUS_PREFIX;
    let mut add = |len: usize| {
        offsets.push(at);
        at += len + packet::FAST_SEGMENT_OVERHEAD;
    };
    match p.instruction {
        inst::FAST_SYNC_READ if p.params.len() > 4 => {
            let len = usize::from(u16::from_le_bytes([p.params[2], p.params[3]]));
            p.params[4..].iter().for_each(|_| add(len));
        }
        inst::FAST_BULK_READ if !p.params.is_empty() && p.params.len().is_multiple_of(5) => {
            for c in p.params.chunks_exact(5) {
                add(usize::from(u16::from_le_bytes([c[3], c[4]])));
            }
        }
        _ => return None,
    }
    // INST + every segment but the last CRC + the packet's CRC.
    Some(at - packet::FAST_STATUS_PREFIX + 1)
}

/// Length of the packet at the end of `used` (for junk accounting): `used` minus leading junk.
fn packet_len_hint(used: &[u8]) -> usize {
    used.windows(4)
        .position(|w| w == packet::HEADER)
        .map_or(used.len(), |start| used.len() - start)
}

/// A Dynamixel line in simulated time between a host's USB adapter and its servos.
pub type SimDxlWire = HalfDuplexWire<ServoChain>;

impl LineDevices for ServoChain {
    fn timing(&self) -> WireTiming {
        self.timing
    }

    fn receive(&mut self, bytes: &[u8], now: SimInstant) {
        ServoChain::receive(self, bytes, now);
    }

    fn next_reply_at(&self) -> Option<SimInstant> {
        self.replies.next_at()
    }

    fn take_replies_due(&mut self, now: SimInstant, sink: &mut dyn FnMut(SimInstant, &[u8])) {
        self.replies.take_due(now, sink);
    }
}

impl ServoLine for ServoChain {
    fn tick_servos(&mut self, now: SimInstant, plants: &mut [InertiaPlant]) {
        for (servo, plant) in self.servos.iter_mut().zip(plants) {
            servo.tick(now, plant);
        }
    }
}

/// Emulated X-series servos on one line, each turning an [`InertiaPlant`].
pub type DxlRig = LineRig<ServoChain>;

impl LineRig<ServoChain> {
    /// Servos on a line with `timing`, one plant each, their firmware run every `period`.
    ///
    /// # Panics
    /// When the numbers of servos and plants differ.
    pub fn new(
        servos: Vec<XSeriesServo>,
        plants: Vec<InertiaPlant>,
        timing: WireTiming,
        period: Duration,
    ) -> Self {
        assert_eq!(servos.len(), plants.len(), "one plant per servo");
        Self::with_devices(ServoChain::new(servos, timing), plants, period)
    }

    /// A bench rig: servos `(id, model)` on one line with `timing`, answering after
    /// `return_delay`, each turning a small arm link (2 g·m², light friction), firmware at 2 kHz.
    pub fn bench(servos: &[(u8, &DxlModel)], timing: WireTiming, return_delay: Duration) -> Self {
        let emulated = servos
            .iter()
            .map(|&(id, model)| {
                XSeriesServo::new(model, ServoConfig::new(id).on_line(timing.baud, return_delay))
            })
            .collect();
        let plants = servos
            .iter()
            .map(|_| InertiaPlant::new(2e-3, 0.05, 0.02, 0.0))
            .collect();
        Self::new(emulated, plants, timing, Duration::from_micros(500))
    }

    /// The servo at `index`, to inject faults.
    pub fn servo_mut(&mut self, index: usize) -> &mut XSeriesServo {
        &mut self.wire_mut().chain_mut().servos[index]
    }

    /// The servo at `index`.
    pub fn servo(&self, index: usize) -> &XSeriesServo {
        &self.wire().chain().servos[index]
    }
}
