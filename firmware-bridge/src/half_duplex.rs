//! Half-duplex serial servo lines, whatever the protocol: the host asks with an instruction
//! packet, servos answer with status packets, one at a time on one wire (Dynamixel 2.0, Feetech
//! STS/SCS).
//!
//! - Host side: a [`ServoCodec`] frames packets; [`ServoTransport`] is what a driver sees;
//!   [`SerialServoPort`] runs it on a serial device, [`LockstepServoPort`] against a simulated
//!   world.
//! - Servo side: [`LineDevices`] are the servos as they hear and answer the line;
//!   [`HalfDuplexWire`] carries bytes between them and the host's USB adapter in simulated time.

use std::collections::VecDeque;
use std::marker::PhantomData;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use crate::plant::InertiaPlant;
use crate::serial::SerialSimWorld;
use crate::time::{BusInstant, SimInstant};

/// How long bytes take on a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WireTiming {
    /// Bits per second.
    pub baud: u32,
    /// Added to every transfer towards the host (USB adapters buffer: FTDI latency timer).
    pub usb_latency: Duration,
}

impl WireTiming {
    /// A line at `baud` with a 1 ms-latency adapter setting turned down to zero.
    pub const fn new(baud: u32) -> Self {
        Self {
            baud,
            usb_latency: Duration::ZERO,
        }
    }

    /// Wire time of `bytes` bytes (start bit, 8 data bits, stop bit each).
    pub fn bytes_time(&self, bytes: usize) -> Duration {
        let bits = bytes as u64 * 10;
        Duration::from_nanos((bits * 1_000_000_000).div_ceil(u64::from(self.baud.max(1))))
    }
}

/// How long to wait for `bytes` of status packets on a line: their wire time, the servos' return
/// delays, the adapter latency and a margin for the host's scheduler.
pub fn reply_budget(
    baud: u32,
    bytes: usize,
    servos: usize,
    per_servo_delay: Duration,
    slack: Duration,
) -> Duration {
    WireTiming::new(baud).bytes_time(bytes) + per_servo_delay * servos as u32 + slack
}

/// A status packet, its parameters borrowed from the transport's buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatusPacket<'a> {
    /// Sender ID.
    pub id: u8,
    /// Error byte.
    pub error: u8,
    /// Parameters (unstuffed where the protocol stuffs).
    pub params: &'a [u8],
}

/// What went wrong on the line, below the level of servo IDs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum LinkError {
    /// Nothing (complete) arrived before the deadline.
    #[error("no status packet before the deadline")]
    Timeout,
    /// A status packet arrived with a bad CRC or checksum (and was dropped).
    #[error("status packet with a bad CRC or checksum")]
    Crc,
    /// Bytes arrived that are not a status packet (and were dropped).
    #[error("malformed status packet")]
    Malformed,
    /// A status packet reported an instruction error; the transport dropped its contents.
    #[error("status packet with error byte {0:#04x}")]
    ServoError(u8),
    /// The serial device failed.
    #[error("serial port I/O error: {0}")]
    Io(std::io::ErrorKind),
}

/// What a codec found at the front of the bytes a host has read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StatusDecode {
    /// A status packet: sender, error byte, its parameters at `scratch[params]`, and the bytes it
    /// (and any junk before it) used.
    Status {
        /// Sender ID.
        id: u8,
        /// Error byte.
        error: u8,
        /// Where its parameters are in the scratch buffer.
        params: (usize, usize),
        /// Input bytes used.
        used: usize,
    },
    /// A broken or unexpected packet: drop `used` bytes.
    Invalid {
        /// Why.
        error: LinkError,
        /// Input bytes to drop.
        used: usize,
    },
    /// More bytes needed; `skip` leading bytes are junk and can go now.
    Incomplete {
        /// Junk bytes.
        skip: usize,
    },
}

/// A serial servo protocol's framing, as the host needs it.
pub trait ServoCodec {
    /// The bytes every packet starts with.
    const HEADER: &'static [u8];

    /// Encodes an instruction packet into `out`; its length, or `None` when it does not fit.
    fn encode_instruction(id: u8, instruction: u8, params: &[u8], out: &mut [u8]) -> Option<usize>;

    /// The status packet at the front of `input` (parameters written to `scratch`).
    fn decode_status(input: &[u8], scratch: &mut [u8]) -> StatusDecode;
}

/// A half-duplex servo line as a host driver sees it, speaking protocol `Codec`.
pub trait ServoTransport {
    /// The protocol.
    type Codec: ServoCodec;
    /// Timestamps of this transport.
    type Instant: BusInstant;

    /// The transport's clock.
    fn now(&self) -> Self::Instant;

    /// Line speed, for timeouts.
    fn baud(&self) -> u32;

    /// Sends one instruction packet, dropping any unread input first.
    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError>;

    /// The next status packet, waiting until `deadline` at most.
    fn recv_status(&mut self, deadline: Self::Instant) -> Result<StatusPacket<'_>, LinkError>;

    /// Raw bytes from a packet header on: `total` of them, or at `deadline` what has arrived (a
    /// servo that did not answer leaves the packet short). `Timeout` when no header came. For
    /// answers several servos build together (Dynamixel's fast reads), which no codec frames.
    fn recv_raw(&mut self, total: usize, deadline: Self::Instant) -> Result<&[u8], LinkError>;
}

/// A status taken from the reader: sender, error byte, where its parameters are in the scratch.
type Taken = (u8, u8, (usize, usize));

/// Status packets out of the bytes a host has read, through a codec; buffers made once.
#[derive(Debug)]
struct StatusReader<C> {
    rx: Vec<u8>,
    scratch: Vec<u8>,
    /// Bytes of `rx` the status handed out last used.
    consumed: usize,
    codec: PhantomData<C>,
}

impl<C: ServoCodec> StatusReader<C> {
    fn new() -> Self {
        Self {
            rx: Vec::with_capacity(8192),
            scratch: vec![0; 8192],
            consumed: 0,
            codec: PhantomData,
        }
    }

    /// Forgets what was read (a new instruction goes out).
    fn clear(&mut self) {
        self.rx.clear();
        self.consumed = 0;
    }

    /// Drops the status handed out last, before looking for the next.
    fn begin(&mut self) {
        self.rx.drain(..self.consumed);
        self.consumed = 0;
    }

    /// The next status in what has been read — `(id, error, parameter range)` — an error for a
    /// broken packet (dropped), or `None`: more bytes needed.
    fn take(&mut self) -> Option<Result<Taken, LinkError>> {
        match C::decode_status(&self.rx, &mut self.scratch) {
            StatusDecode::Status {
                id,
                error,
                params,
                used,
            } => {
                self.consumed = used;
                Some(Ok((id, error, params)))
            }
            StatusDecode::Invalid { error, used } => {
                self.rx.drain(..used.min(self.rx.len()));
                Some(Err(error))
            }
            StatusDecode::Incomplete { skip } => {
                self.rx.drain(..skip.min(self.rx.len()));
                None
            }
        }
    }

    fn status(&self, id: u8, error: u8, (from, to): (usize, usize)) -> StatusPacket<'_> {
        StatusPacket {
            id,
            error,
            params: &self.scratch[from..to],
        }
    }

    /// Bytes from the first packet header on (junk before it dropped; a partial header kept).
    fn align_to_header(&mut self) -> usize {
        let h = C::HEADER;
        match self.rx.windows(h.len()).position(|w| w == h) {
            Some(start) => {
                self.rx.drain(..start);
                self.rx.len()
            }
            None => {
                let keep = self.rx.len().min(h.len() - 1);
                self.rx.drain(..self.rx.len() - keep);
                0
            }
        }
    }

    /// Hands out the first `n` bytes and marks them used.
    fn hand_out(&mut self, n: usize) -> &[u8] {
        self.consumed = n;
        &self.rx[..n]
    }
}

/// A serial device (a USB adapter, or the pseudo-terminal an emulator serves) framed by codec
/// `C`.
#[derive(Debug)]
pub struct SerialServoPort<C> {
    port: serial2::SerialPort,
    baud: u32,
    tx: Vec<u8>,
    reader: StatusReader<C>,
    chunk: Vec<u8>,
}

impl<C: ServoCodec> SerialServoPort<C> {
    /// A port already opened and set up at `baud` (8N1, raw); each protocol's module opens its
    /// own (`open`).
    pub fn from_port(port: serial2::SerialPort, baud: u32) -> Self {
        Self {
            port,
            baud,
            tx: vec![0; 8192],
            reader: StatusReader::new(),
            chunk: vec![0; 4096],
        }
    }

    /// Reads what arrives by `deadline` into the reader; `Ok(false)` at the deadline.
    fn fill(&mut self, deadline: std::time::Instant) -> Result<bool, LinkError> {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        self.port
            .set_read_timeout(left.max(Duration::from_micros(1)))
            .map_err(|e| LinkError::Io(e.kind()))?;
        match std::io::Read::read(&mut self.port, &mut self.chunk) {
            Ok(0) => Ok(false),
            Ok(n) => {
                self.reader.rx.extend_from_slice(&self.chunk[..n]);
                Ok(true)
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Ok(false),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(true),
            Err(e) => Err(LinkError::Io(e.kind())),
        }
    }
}

impl<C: ServoCodec> ServoTransport for SerialServoPort<C> {
    type Codec = C;
    type Instant = std::time::Instant;

    fn now(&self) -> std::time::Instant {
        std::time::Instant::now()
    }

    fn baud(&self) -> u32 {
        self.baud
    }

    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError> {
        let n = C::encode_instruction(id, instruction, params, &mut self.tx).ok_or(LinkError::Malformed)?;
        // Drop whatever arrived unasked before the instruction goes out.
        self.reader.clear();
        self.port
            .discard_input_buffer()
            .map_err(|e| LinkError::Io(e.kind()))?;
        std::io::Write::write_all(&mut self.port, &self.tx[..n]).map_err(|e| LinkError::Io(e.kind()))
    }

    fn recv_status(&mut self, deadline: std::time::Instant) -> Result<StatusPacket<'_>, LinkError> {
        self.reader.begin();
        loop {
            match self.reader.take() {
                Some(Ok((id, error, params))) => return Ok(self.reader.status(id, error, params)),
                Some(Err(e)) => return Err(e),
                None => {}
            }
            // What has arrived counts even at the deadline: a scheduler may collect late.
            if !self.fill(deadline)? {
                return Err(LinkError::Timeout);
            }
        }
    }

    fn recv_raw(&mut self, total: usize, deadline: std::time::Instant) -> Result<&[u8], LinkError> {
        self.reader.begin();
        loop {
            let have = self.reader.align_to_header();
            let now = std::time::Instant::now();
            if have >= total || (now >= deadline && have > 0) {
                return Ok(self.reader.hand_out(have.min(total)));
            }
            if now >= deadline {
                return Err(LinkError::Timeout);
            }
            self.fill(deadline)?;
        }
    }
}

/// The host's end of line `line` of a simulated world, framed by codec `C`: waiting for a status
/// packet runs the world forward event by event.
#[derive(Debug)]
pub struct LockstepServoPort<W, C> {
    world: Arc<Mutex<W>>,
    line: usize,
    baud: u32,
    tx: Vec<u8>,
    reader: StatusReader<C>,
}

impl<W: SerialSimWorld, C: ServoCodec> LockstepServoPort<W, C> {
    /// A port on line `line` of `world`, which runs at `baud`.
    pub fn new(world: Arc<Mutex<W>>, line: usize, baud: u32) -> Self {
        Self {
            world,
            line,
            baud,
            tx: vec![0; 8192],
            reader: StatusReader::new(),
        }
    }

    fn world(&self) -> MutexGuard<'_, W> {
        self.world.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The shared world.
    pub fn shared_world(&self) -> &Arc<Mutex<W>> {
        &self.world
    }

    /// Takes what reached the host; if nothing did, runs the world to its next event (or the
    /// deadline). `Ok(false)` once the deadline has passed with nothing new.
    fn fill(&mut self, deadline: SimInstant) -> bool {
        let mut world = self.world.lock().unwrap_or_else(PoisonError::into_inner);
        let had = self.reader.rx.len();
        world.host_receive(self.line, &mut self.reader.rx);
        if self.reader.rx.len() > had {
            return true;
        }
        if world.now() >= deadline {
            return false;
        }
        let from = world.now();
        world.step_until(deadline.max(from));
        world.host_receive(self.line, &mut self.reader.rx);
        true
    }
}

impl<W: SerialSimWorld, C: ServoCodec> ServoTransport for LockstepServoPort<W, C> {
    type Codec = C;
    type Instant = SimInstant;

    fn now(&self) -> SimInstant {
        self.world().now()
    }

    fn baud(&self) -> u32 {
        self.baud
    }

    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError> {
        let n = C::encode_instruction(id, instruction, params, &mut self.tx).ok_or(LinkError::Malformed)?;
        let mut world = self.world.lock().unwrap_or_else(PoisonError::into_inner);
        // Drop whatever arrived unasked before the instruction goes out.
        world.host_receive(self.line, &mut self.reader.rx);
        self.reader.clear();
        world.host_transmit(self.line, &self.tx[..n]);
        Ok(())
    }

    fn recv_status(&mut self, deadline: SimInstant) -> Result<StatusPacket<'_>, LinkError> {
        self.reader.begin();
        loop {
            match self.reader.take() {
                Some(Ok((id, error, params))) => return Ok(self.reader.status(id, error, params)),
                Some(Err(e)) => return Err(e),
                None => {}
            }
            // What has arrived counts even at the deadline: a scheduler may collect late.
            if !self.fill(deadline) {
                return Err(LinkError::Timeout);
            }
        }
    }

    fn recv_raw(&mut self, total: usize, deadline: SimInstant) -> Result<&[u8], LinkError> {
        self.reader.begin();
        loop {
            let have = self.reader.align_to_header();
            let passed = self.world().now() >= deadline;
            if have >= total || (passed && have > 0) {
                return Ok(self.reader.hand_out(have.min(total)));
            }
            if !self.fill(deadline) {
                return match have {
                    0 => Err(LinkError::Timeout),
                    _ => Ok(self.reader.hand_out(have.min(total))),
                };
            }
        }
    }
}

/// What an injected reply fault does to a servo's status packets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplyFault {
    /// The servo executes the instruction but does not answer.
    Silent,
    /// The status packet goes out with a corrupted CRC or checksum.
    CorruptCrc,
    /// The status packet carries this ID instead of the servo's.
    WrongId(u8),
    /// The status packet starts this much later than the Return Delay Time says.
    Delay(Duration),
}

/// The servos of one line as they hear and answer it, whatever their protocol.
pub trait LineDevices {
    /// The line's timing.
    fn timing(&self) -> WireTiming;
    /// Bytes whose last bit arrived at `now`; complete packets are executed at once.
    fn receive(&mut self, bytes: &[u8], now: SimInstant);
    /// When the next status packet starts, if one is pending.
    fn next_reply_at(&self) -> Option<SimInstant>;
    /// Hands every status packet that starts by `now` to `sink(start, bytes)`, in start order.
    fn take_replies_due(&mut self, now: SimInstant, sink: &mut dyn FnMut(SimInstant, &[u8]));
}

/// Status packets servos have queued, each with the time its first byte goes on the wire: the
/// bytes in one buffer made once, reused whenever nothing is pending.
#[derive(Debug)]
pub struct ReplySchedule {
    scheduled: VecDeque<(SimInstant, usize, usize)>,
    bytes: Vec<u8>,
}

impl ReplySchedule {
    /// Room for `packets` packets of `bytes` bytes in all before anything grows.
    pub fn with_capacity(packets: usize, bytes: usize) -> Self {
        Self {
            scheduled: VecDeque::with_capacity(packets),
            bytes: Vec::with_capacity(bytes),
        }
    }

    /// The buffer the next packet is written at the end of (emptied first when nothing is
    /// pending).
    pub fn bytes_mut(&mut self) -> &mut Vec<u8> {
        if self.scheduled.is_empty() {
            self.bytes.clear();
        }
        &mut self.bytes
    }

    /// The bytes from `from` to the buffer's end go on the wire at `start`.
    pub fn push(&mut self, start: SimInstant, from: usize) {
        self.scheduled.push_back((start, from, self.bytes.len()));
    }

    /// When the next packet starts, if one is pending.
    pub fn next_at(&self) -> Option<SimInstant> {
        self.scheduled.iter().map(|s| s.0).min()
    }

    /// Hands every packet that starts by `now` to `sink(start, bytes)`, in start order.
    pub fn take_due(&mut self, now: SimInstant, sink: &mut dyn FnMut(SimInstant, &[u8])) {
        while let Some(i) = (0..self.scheduled.len())
            .filter(|&i| self.scheduled[i].0 <= now)
            .min_by_key(|&i| self.scheduled[i].0)
        {
            if let Some((start, from, to)) = self.scheduled.remove(i) {
                sink(start, &self.bytes[from..to]);
            }
        }
    }
}

/// Servos on a line that run their firmware on plants.
pub trait ServoLine: LineDevices {
    /// One firmware period at `now`: each servo samples its plant and applies its torque.
    fn tick_servos(&mut self, now: SimInstant, plants: &mut [InertiaPlant]);
}

/// Emulated servos on one line, each turning an [`InertiaPlant`]: the smallest world a driver
/// can be tested against (the mirrored simulator does the same with MuJoCo joints).
#[derive(Debug)]
pub struct LineRig<D> {
    wire: HalfDuplexWire<D>,
    plants: Vec<InertiaPlant>,
    now: SimInstant,
    period: Duration,
    next_tick: SimInstant,
    busy: Duration,
}

impl<D: ServoLine> LineRig<D> {
    /// `devices` on a wire, one plant each, their firmware run every `period`.
    pub fn with_devices(devices: D, plants: Vec<InertiaPlant>, period: Duration) -> Self {
        Self {
            wire: HalfDuplexWire::new(devices),
            plants,
            now: SimInstant::ZERO,
            period,
            next_tick: SimInstant::ZERO,
            busy: Duration::ZERO,
        }
    }

    /// The wire and its servos.
    pub fn wire(&self) -> &HalfDuplexWire<D> {
        &self.wire
    }

    /// The wire, to reach the servos.
    pub fn wire_mut(&mut self) -> &mut HalfDuplexWire<D> {
        &mut self.wire
    }

    /// The plants.
    pub fn plants(&self) -> &[InertiaPlant] {
        &self.plants
    }

    /// The plant at `index`, to push it around.
    pub fn plant_mut(&mut self, index: usize) -> &mut InertiaPlant {
        &mut self.plants[index]
    }

    /// CPU time spent inside the world (firmware, plants, wire), for benches that separate the
    /// host's share.
    pub fn busy(&self) -> Duration {
        self.busy
    }
}

impl<D: ServoLine> crate::time::SimWorld for LineRig<D> {
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
            self.wire.devices.tick_servos(self.now, &mut self.plants);
            let dt = self.period.as_secs_f64();
            for plant in &mut self.plants {
                plant.integrate(dt);
            }
            self.next_tick = self.next_tick + self.period;
        }
        self.busy += started.elapsed();
        self.now
    }
}

impl<D: ServoLine> SerialSimWorld for LineRig<D> {
    // A rig has one line: whatever line the host names, it is this one.
    fn host_transmit(&mut self, _line: usize, bytes: &[u8]) {
        self.wire.host_transmit(self.now, bytes);
    }

    fn host_receive(&mut self, _line: usize, out: &mut Vec<u8>) {
        self.wire.host_receive(self.now, out);
    }
}

/// Transmit buffer of the emulated USB serial adapter, bytes (an FTDI FT232's is 256 B–4 KB).
pub const ADAPTER_BUFFER_BYTES: usize = 4096;

/// A line in simulated time between a host (through its USB serial adapter) and the servos on it.
#[derive(Debug)]
pub struct HalfDuplexWire<D> {
    devices: D,
    /// Bytes the host adapter dropped because its transmit buffer was full.
    overflowed: u64,
    line_free_at: SimInstant,
    to_servos: VecDeque<(SimInstant, usize)>,
    to_servos_bytes: VecDeque<u8>,
    to_host: VecDeque<(SimInstant, usize)>,
    to_host_bytes: VecDeque<u8>,
    chunk: Vec<u8>,
}

impl<D: LineDevices> HalfDuplexWire<D> {
    /// A wire to `devices`.
    pub fn new(devices: D) -> Self {
        Self {
            devices,
            overflowed: 0,
            line_free_at: SimInstant::ZERO,
            to_servos: VecDeque::with_capacity(16),
            to_servos_bytes: VecDeque::with_capacity(2 * ADAPTER_BUFFER_BYTES),
            to_host: VecDeque::with_capacity(64),
            to_host_bytes: VecDeque::with_capacity(8192),
            chunk: Vec::with_capacity(2 * ADAPTER_BUFFER_BYTES),
        }
    }

    /// The servos' side.
    pub fn chain(&self) -> &D {
        &self.devices
    }

    /// The servos' side, to inject faults.
    pub fn chain_mut(&mut self) -> &mut D {
        &mut self.devices
    }

    /// The host starts sending `bytes` at `now` (after anything it is still sending).
    pub fn host_transmit(&mut self, now: SimInstant, bytes: &[u8]) {
        // A USB serial adapter buffers a few kilobytes on its way to the line; what a host sends
        // beyond that is lost (counted), as on the real adapter — a flood neither grows memory nor
        // keeps the line busy for seconds.
        let room = ADAPTER_BUFFER_BYTES.saturating_sub(self.to_servos_bytes.len());
        let taken = bytes.len().min(room);
        self.overflowed += (bytes.len() - taken) as u64;
        if taken == 0 {
            return;
        }
        let bytes = &bytes[..taken];
        let start = self.line_free_at.max(now);
        let arrival = start + self.devices.timing().bytes_time(bytes.len());
        self.line_free_at = arrival;
        self.to_servos.push_back((arrival, bytes.len()));
        self.to_servos_bytes.extend(bytes);
    }

    /// Bytes dropped because the adapter's transmit buffer was full.
    pub fn overflowed(&self) -> u64 {
        self.overflowed
    }

    /// The next time after `now` something happens on the wire (bytes already delivered to the
    /// host wait for [`Self::host_receive`] and are no event).
    pub fn next_event(&self, now: SimInstant) -> Option<SimInstant> {
        [
            self.to_servos.front().map(|e| e.0),
            self.devices.next_reply_at(),
            self.to_host.iter().map(|e| e.0).find(|&t| t > now),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Runs everything due by `now`.
    pub fn advance(&mut self, now: SimInstant) {
        while let Some(&(arrival, n)) = self.to_servos.front() {
            if arrival > now {
                break;
            }
            self.to_servos.pop_front();
            self.chunk.clear();
            self.chunk.extend(self.to_servos_bytes.drain(..n));
            self.devices.receive(&self.chunk, arrival);
        }
        let timing = self.devices.timing();
        let (to_host, to_host_bytes) = (&mut self.to_host, &mut self.to_host_bytes);
        self.devices.take_replies_due(now, &mut |start, bytes| {
            let delivered = start + timing.bytes_time(bytes.len()) + timing.usb_latency;
            to_host.push_back((delivered, bytes.len()));
            to_host_bytes.extend(bytes);
        });
    }

    /// Moves the bytes that reached the host by `now` into `out`.
    pub fn host_receive(&mut self, now: SimInstant, out: &mut Vec<u8>) {
        while let Some(&(at, n)) = self.to_host.front() {
            if at > now {
                break;
            }
            self.to_host.pop_front();
            out.extend(self.to_host_bytes.drain(..n));
        }
    }
}
