//! How the host driver reaches a line: send one instruction packet, receive status packets.
//!
//! [`SerialDxlPort`] is the real thing: the `dynamixel2` crate's bus on a serial device (a USB
//! adapter, or the pseudo-terminal the emulator serves). [`LockstepDxlPort`] runs the same driver
//! against a simulated world in lockstep, encoding with the shared codec.

use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use super::packet::{self, Decoded};
use crate::serial::SerialSimWorld;
use crate::time::{BusInstant, SimInstant};

/// A status packet, its parameters borrowed from the transport's buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StatusPacket<'a> {
    /// Sender ID.
    pub id: u8,
    /// Error byte (bit 7: alert).
    pub error: u8,
    /// Parameters, unstuffed.
    pub params: &'a [u8],
}

/// What went wrong on the line, below the level of servo IDs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum LinkError {
    /// Nothing (complete) arrived before the deadline.
    #[error("no status packet before the deadline")]
    Timeout,
    /// A status packet arrived with a bad CRC (and was dropped).
    #[error("status packet with a bad CRC")]
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

/// A half-duplex Dynamixel line as the host driver sees it.
pub trait DxlTransport {
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

    /// The raw bytes of a fast read's status packet (no unstuffing: fast replies are not
    /// stuffed), from its header on: `total` of them, or at `deadline` what has arrived (a
    /// servo that did not answer leaves the packet short). `Timeout` when no header came.
    fn recv_fast(&mut self, total: usize, deadline: Self::Instant) -> Result<&[u8], LinkError>;
}

/// A serial device opened and set up by the `dynamixel2` crate, its packets framed by this
/// project's codec ([`packet`]): dynamixel2 0.9.1's byte stuffing misses an `FF FF FD` that
/// follows another `FF` (its pattern matcher restarts from scratch), both ways — a status with a
/// velocity of −1 before a position ending in `FD` came out one byte long and was refused.
#[derive(Debug)]
pub struct SerialDxlPort {
    bus: dynamixel2::Bus<Vec<u8>, Vec<u8>>,
    /// A second handle on the bus's serial port, whose read timeout follows each deadline.
    port: dynamixel2::serial2::SerialPort,
    tx: Vec<u8>,
    reader: StatusReader,
    chunk: Vec<u8>,
}

impl SerialDxlPort {
    /// Opens `path` at `baud` (8N1, raw).
    pub fn open(path: &str, baud: u32) -> std::io::Result<Self> {
        let bus = dynamixel2::Bus::open_with_buffers(path, baud, vec![0; 8192], vec![0; 4096])?;
        let port = bus.serial_port().try_clone()?;
        Ok(Self {
            bus,
            port,
            tx: vec![0; 8192],
            reader: StatusReader::new(),
            chunk: vec![0; 4096],
        })
    }
}

/// Status packets out of the bytes a host has read, through the project's own codec (CRC, byte
/// stuffing); buffers made once.
#[derive(Debug)]
struct StatusReader {
    rx: Vec<u8>,
    scratch: Vec<u8>,
    /// Bytes of `rx` the status handed out last used.
    consumed: usize,
}

impl StatusReader {
    fn new() -> Self {
        Self {
            rx: Vec::with_capacity(8192),
            scratch: vec![0; 8192],
            consumed: 0,
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

    /// The next status in what has been read — `(id, error, parameter count)`, its parameters in
    /// [`Self::params`] — an error for a broken packet (dropped), or `None`: more bytes needed.
    fn take(&mut self) -> Option<Result<(u8, u8, usize), LinkError>> {
        let outcome = match packet::decode(&self.rx, &mut self.scratch) {
            Decoded::Packet(p, used) if p.instruction == packet::STATUS => {
                Some(Ok((p.id, p.error.unwrap_or(0), p.params.len(), used)))
            }
            Decoded::Packet(_, used) => Some(Err((LinkError::Malformed, used))),
            Decoded::Invalid(packet::PacketError::Crc { .. }, _, skip) => {
                // Skip the whole packet, as `dynamixel2` does, not just its header.
                let len = self
                    .rx
                    .get(skip + 1..skip + 3)
                    .map_or(0, |l| usize::from(u16::from_le_bytes([l[0], l[1]])));
                Some(Err((LinkError::Crc, (skip + 3 + len).min(self.rx.len()))))
            }
            Decoded::Invalid(_, _, skip) => Some(Err((LinkError::Malformed, skip))),
            Decoded::Incomplete { skip } => {
                self.rx.drain(..skip);
                None
            }
        };
        match outcome? {
            Ok((id, error, len, used)) => {
                self.consumed = used;
                Some(Ok((id, error, len)))
            }
            Err((e, used)) => {
                self.rx.drain(..used);
                Some(Err(e))
            }
        }
    }

    /// The parameters of the status [`Self::take`] returned last.
    fn params(&self, len: usize) -> &[u8] {
        &self.scratch[2..2 + len]
    }

    /// Bytes from the first packet header on (junk before it dropped; a partial header kept).
    fn align_to_header(&mut self) -> usize {
        match self.rx.windows(4).position(|w| w == packet::HEADER) {
            Some(start) => {
                self.rx.drain(..start);
                self.rx.len()
            }
            None => {
                let keep = self.rx.len().min(3);
                self.rx.drain(..self.rx.len() - keep);
                0
            }
        }
    }

    /// Hands out the first `n` bytes (the fast packet) and marks them used.
    fn hand_out(&mut self, n: usize) -> &[u8] {
        self.consumed = n;
        &self.rx[..n]
    }
}

impl DxlTransport for SerialDxlPort {
    type Instant = std::time::Instant;

    fn now(&self) -> std::time::Instant {
        std::time::Instant::now()
    }

    fn baud(&self) -> u32 {
        self.bus.baud_rate()
    }

    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError> {
        // Encoded here too: dynamixel2's stuffing misses the same `FF FF FF FD` its reading does.
        let n = packet::encode_instruction(id, instruction, params, &mut self.tx)
            .map_err(|_| LinkError::Malformed)?;
        // Like `dynamixel2`, drop whatever arrived unasked before the instruction goes out.
        self.reader.clear();
        self.port
            .discard_input_buffer()
            .map_err(|e| LinkError::Io(e.kind()))?;
        self.port
            .write_all(&self.tx[..n])
            .map_err(|e| LinkError::Io(e.kind()))
    }

    fn recv_status(&mut self, deadline: std::time::Instant) -> Result<StatusPacket<'_>, LinkError> {
        self.reader.begin();
        loop {
            match self.reader.take() {
                Some(Ok((id, error, len))) => {
                    return Ok(StatusPacket {
                        id,
                        error,
                        params: self.reader.params(len),
                    });
                }
                Some(Err(e)) => return Err(e),
                None => {}
            }
            // What has arrived counts even at the deadline: a scheduler may collect late.
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            self.port
                .set_read_timeout(left.max(Duration::from_micros(1)))
                .map_err(|e| LinkError::Io(e.kind()))?;
            match self.port.read(&mut self.chunk) {
                Ok(0) => return Err(LinkError::Timeout),
                Ok(n) => self.reader.rx.extend_from_slice(&self.chunk[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => return Err(LinkError::Timeout),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(LinkError::Io(e.kind())),
            }
        }
    }

    fn recv_fast(&mut self, total: usize, deadline: std::time::Instant) -> Result<&[u8], LinkError> {
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
            self.port
                .set_read_timeout((deadline - now).max(Duration::from_micros(1)))
                .map_err(|e| LinkError::Io(e.kind()))?;
            match self.port.read(&mut self.chunk) {
                Ok(n) => self.reader.rx.extend_from_slice(&self.chunk[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Err(LinkError::Io(e.kind())),
            }
        }
    }
}

/// The host's end of line `line` of a simulated world: waiting for a status packet runs the
/// world forward event by event.
#[derive(Debug)]
pub struct LockstepDxlPort<W> {
    world: Arc<Mutex<W>>,
    line: usize,
    baud: u32,
    tx: Vec<u8>,
    reader: StatusReader,
}

impl<W: SerialSimWorld> LockstepDxlPort<W> {
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
}

impl<W: SerialSimWorld> DxlTransport for LockstepDxlPort<W> {
    type Instant = SimInstant;

    fn now(&self) -> SimInstant {
        self.world().now()
    }

    fn baud(&self) -> u32 {
        self.baud
    }

    fn send(&mut self, id: u8, instruction: u8, params: &[u8]) -> Result<(), LinkError> {
        let n = packet::encode_instruction(id, instruction, params, &mut self.tx)
            .map_err(|_| LinkError::Malformed)?;
        let mut world = self.world.lock().unwrap_or_else(PoisonError::into_inner);
        // Like `dynamixel2`, drop whatever arrived unasked before the instruction goes out.
        world.host_receive(self.line, &mut self.reader.rx);
        self.reader.clear();
        world.host_transmit(self.line, &self.tx[..n]);
        Ok(())
    }

    fn recv_status(&mut self, deadline: SimInstant) -> Result<StatusPacket<'_>, LinkError> {
        self.reader.begin();
        loop {
            match self.reader.take() {
                Some(Ok((id, error, len))) => {
                    return Ok(StatusPacket {
                        id,
                        error,
                        params: self.reader.params(len),
                    });
                }
                Some(Err(e)) => return Err(e),
                None => {}
            }
            let mut world = self.world.lock().unwrap_or_else(PoisonError::into_inner);
            // What has arrived counts even at the deadline: a scheduler may collect late.
            let had = self.reader.rx.len();
            world.host_receive(self.line, &mut self.reader.rx);
            if self.reader.rx.len() > had {
                continue;
            }
            if world.now() >= deadline {
                return Err(LinkError::Timeout);
            }
            let from = world.now();
            world.step_until(deadline.max(from));
            world.host_receive(self.line, &mut self.reader.rx);
        }
    }

    fn recv_fast(&mut self, total: usize, deadline: SimInstant) -> Result<&[u8], LinkError> {
        self.reader.begin();
        loop {
            let have = self.reader.align_to_header();
            let mut world = self.world.lock().unwrap_or_else(PoisonError::into_inner);
            if have >= total || (world.now() >= deadline && have > 0) {
                drop(world);
                return Ok(self.reader.hand_out(have.min(total)));
            }
            let had = self.reader.rx.len();
            world.host_receive(self.line, &mut self.reader.rx);
            if self.reader.rx.len() > had {
                continue;
            }
            if world.now() >= deadline {
                return Err(LinkError::Timeout);
            }
            // The next byte's event, or the deadline.
            let from = world.now();
            world.step_until(deadline.max(from));
        }
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
    super::wire::WireTiming::new(baud).bytes_time(bytes) + per_servo_delay * servos as u32 + slack
}
